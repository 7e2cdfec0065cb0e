"""A GNSS trace: fixes in WGS84 with whatever else the recording carries (NaN where it carries nothing)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tavf_mapkit.errors import InputError

_EARTH_RADIUS = 6_371_008.8
_OPTIONAL = ("t", "alt", "speed", "heading", "accuracy")


@dataclass(frozen=True, eq=False)
class Trace:
    """Fixes in recording order.

    lat, lon: degrees (WGS84). t: seconds (Unix time where the file has absolute times, else the file's own
    clock). alt: metres. speed: m/s. heading: degrees clockwise from north. accuracy: metres (1 sigma or the
    recorder's horizontal accuracy). Missing values are NaN; ``has("speed")`` tells whether any is known.
    """

    lat: np.ndarray
    lon: np.ndarray
    t: np.ndarray
    alt: np.ndarray
    speed: np.ndarray
    heading: np.ndarray
    accuracy: np.ndarray
    source_format: str
    path: str = ""

    @staticmethod
    def build(lat, lon, source_format: str, path: str = "", **optional) -> Trace:
        """Validate and drop fixes without a position; an empty result is an InputError naming the file."""
        lat = np.asarray(lat, dtype=float).ravel()
        lon = np.asarray(lon, dtype=float).ravel()
        n = len(lat)
        if len(lon) != n:
            raise InputError("latitude and longitude counts differ", file=path or None)
        columns = {}
        for name in _OPTIONAL:
            value = optional.pop(name, None)
            column = np.full(n, np.nan) if value is None else np.asarray(value, dtype=float).ravel()
            if len(column) != n:
                raise InputError(f"{name} has {len(column)} values for {n} fixes", file=path or None)
            columns[name] = column
        if optional:
            raise TypeError(f"unknown trace fields: {sorted(optional)}")
        keep = np.isfinite(lat) & np.isfinite(lon)
        if not np.any(keep):
            raise InputError("the trace has no fixes (empty trace)", file=path or None)
        lat, lon = lat[keep], lon[keep]
        if np.any(np.abs(lat) > 90) or np.any(np.abs(lon) > 180):
            bad = int(np.flatnonzero((np.abs(lat) > 90) | (np.abs(lon) > 180))[0])
            raise InputError(f"fix {bad + 1} is not a WGS84 position (lat {lat[bad]:g}, lon {lon[bad]:g})",
                             file=path or None)
        for array in (lat, lon):
            array.flags.writeable = False
        kept = {name: column[keep] for name, column in columns.items()}
        for column in kept.values():
            column.flags.writeable = False
        return Trace(lat, lon, source_format=source_format, path=path, **kept)

    def __len__(self) -> int:
        return len(self.lat)

    def has(self, name: str) -> bool:
        return bool(np.any(np.isfinite(getattr(self, name))))

    def local_xy(self, georeference) -> tuple[np.ndarray, np.ndarray]:
        """Positions in a map's local coordinates (``GeoReference.wgs84_to_local``)."""
        x, y = georeference.wgs84_to_local(self.lon, self.lat)
        return np.asarray(x, dtype=float), np.asarray(y, dtype=float)

    def local_heading(self, georeference) -> np.ndarray:
        """Heading in the map's frame (radians, counter-clockwise from +x), NaN where unknown.

        A point 1 m ahead along the compass heading is projected too, so grid convergence and the map's
        <offset> rotation are taken into account exactly.
        """
        heading = np.radians(self.heading)
        lat = np.radians(self.lat)
        ahead_lat = self.lat + np.degrees(np.cos(heading) / _EARTH_RADIUS)
        ahead_lon = self.lon + np.degrees(np.sin(heading) / (_EARTH_RADIUS * np.cos(lat)))
        finite = np.isfinite(heading)
        x0, y0 = georeference.wgs84_to_local(self.lon, self.lat)
        x1, y1 = georeference.wgs84_to_local(np.where(finite, ahead_lon, self.lon), np.where(finite, ahead_lat,
                                                                                             self.lat))
        return np.where(finite, np.arctan2(np.asarray(y1) - y0, np.asarray(x1) - x0), np.nan)

    def relative_time(self) -> np.ndarray:
        """Seconds since the first timed fix (NaN where untimed)."""
        finite = self.t[np.isfinite(self.t)]
        return self.t - (finite[0] if len(finite) else 0.0)
