"""Which numbers a real road map can hold, and which only a broken writer produces.

netconvert marks a position it failed to compute with SUMO's invalid-position sentinel (Position::INVALID,
-2**30 m in x and y) and sometimes writes it as a planView vertex; a one-character edit makes a road 5e12 m
long. Such numbers are finite, so the reader accepts them, and every consumer that allocates by length or
area would turn them into terabyte arrays. This module names them; ``budget`` (what samplers may allocate)
and ``repair`` (the build's opendrive stage) act on them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: |x| and |y| of SUMO's Position::INVALID (src/utils/geom/Position.cpp: -1024 * 1024 * 1024)
SUMO_INVALID_POSITION = 1073741824.0
#: m; no projected coordinate on Earth is larger, zone-prefixed Gauss-Krueger/UTM eastings (< 6e7) included
COORDINATE_LIMIT = 1e8


def off_earth(x, y) -> np.ndarray:
    """True where (x, y) cannot be a place on Earth (SUMO's sentinel included; NaN too)."""
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    return ~((np.abs(x) <= COORDINATE_LIMIT) & (np.abs(y) <= COORDINATE_LIMIT))


def vertex_problem(x: float, y: float) -> str | None:
    """Why (x, y) cannot be a vertex of a real map (one phrase), or None when it can."""
    if not off_earth(x, y):
        return None
    if not (np.isfinite(x) and np.isfinite(y)):
        return f"x={x:.6g}, y={y:.6g} is not a number"
    if any(abs(abs(v) - SUMO_INVALID_POSITION) <= 1e-3 * SUMO_INVALID_POSITION for v in (x, y)):
        return (f"x={x:.10g}, y={y:.10g} is SUMO's invalid-position sentinel (-2^30 m): netconvert could not "
                "compute this vertex")
    return f"x={x:.6g}, y={y:.6g} is not a place on Earth (|x| or |y| above {COORDINATE_LIMIT:.0e} m)"


@dataclass(frozen=True)
class Extent:
    """An axis-aligned box in local map coordinates (metres)."""

    west: float
    south: float
    east: float
    north: float

    @staticmethod
    def around(x, y) -> Extent | None:
        """The bounding box of the points that are on Earth; None when there are none."""
        x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        keep = ~off_earth(x, y)
        if not np.any(keep):
            return None
        x, y = x[keep], y[keep]
        return Extent(float(x.min()), float(y.min()), float(x.max()), float(y.max()))

    @property
    def diagonal(self) -> float:
        return float(np.hypot(self.east - self.west, self.north - self.south))

    def outside(self, x, y, margin: float) -> np.ndarray:
        """True where a point lies more than ``margin`` metres outside the box (NaN counts as outside)."""
        x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        inside = ((x >= self.west - margin) & (x <= self.east + margin)
                  & (y >= self.south - margin) & (y <= self.north + margin))
        return ~inside

    def describe(self) -> str:
        return f"x {self.west:.0f}..{self.east:.0f}, y {self.south:.0f}..{self.north:.0f}"


def length_text(metres: float) -> str:
    """A distance for messages: '297 m', '12.4 km', '5e+12 m'."""
    if not np.isfinite(metres) or metres >= 1e7:
        return f"{metres:.3g} m"
    return f"{metres / 1000:.3g} km" if metres >= 1000 else f"{metres:.3g} m"
