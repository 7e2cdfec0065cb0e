"""Simulated GNSS: the true position plus per-axis bias and Gaussian noise, reported as WGS84 lat/lon/alt.

Noise is applied in the map's local frame (x east, y north, z up for the transverse Mercator projections
mapkit builds use; grid convergence is below 0.1 degree within a city) and then converted with the map's
georeference, so a zero-noise fix converts back to the true position exactly (up to PROJ's round trip).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from twin.sensors.fix import GnssFix


@dataclass(frozen=True)
class GnssConfig:
    rate_hz: float = 10.0
    sigma: tuple[float, float, float] = (0.0, 0.0, 0.0)  # m (east, north, up)
    bias: tuple[float, float, float] = (0.0, 0.0, 0.0)  # m


class GnssSensor:
    def __init__(self, georeference, config: GnssConfig, rng: np.random.Generator, dt: float):
        if georeference is None:
            raise ValueError("the map has no geoReference: GNSS needs one")
        if config.rate_hz <= 0:
            raise ValueError("GNSS rate must be positive")
        self.georeference = georeference
        self.config = config
        self.rng = rng
        self.every = max(round(1.0 / (config.rate_hz * dt)), 1)
        self._sigma = np.asarray(config.sigma, dtype=float)
        self._bias = np.asarray(config.bias, dtype=float)
        self._z0 = float(getattr(georeference.offset, "z", 0.0) or 0.0)

    def due(self, step: int) -> bool:
        return step % self.every == 0

    def measure_many(self, t, x, y, z) -> tuple[np.ndarray, ...]:
        """(lat, lon, alt, noisy x, noisy y, noisy z) for arrays of true positions; draws 3 normals per fix."""
        x, y, z = (np.atleast_1d(np.asarray(v, dtype=float)) for v in (x, y, z))
        noise = self.rng.standard_normal((len(x), 3)) * self._sigma + self._bias
        nx_, ny_, nz_ = x + noise[:, 0], y + noise[:, 1], z + noise[:, 2]
        lon, lat = self.georeference.local_to_wgs84(nx_, ny_)
        return np.asarray(lat), np.asarray(lon), nz_ + self._z0, nx_, ny_, nz_

    def measure(self, t: float, x: float, y: float, z: float) -> GnssFix:
        lat, lon, alt, nx_, ny_, nz_ = self.measure_many(t, [x], [y], [z])
        sigma = float(np.hypot(self._sigma[0], self._sigma[1]))
        return GnssFix(float(t), float(lat[0]), float(lon[0]), float(alt[0]), float(nx_[0]), float(ny_[0]),
                       float(nz_[0]), sigma)
