"""The reference line of a road: its planView geometries as one function of s."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from tavf_mapkit.opendrive.geometry import Geometry, GeometryTable


@dataclass(frozen=True, eq=False)
class ReferenceLine:
    geometries: tuple[Geometry, ...]

    @cached_property
    def table(self) -> GeometryTable:
        return GeometryTable.from_geometries(self.geometries)

    def geometry_index(self, s: np.ndarray) -> np.ndarray:
        """Index of the geometry that governs each s; zero-length geometries are never chosen over a successor."""
        s = np.atleast_1d(np.asarray(s, dtype=float))
        return self.table.locate(np.zeros(len(s), dtype=np.int64), s)[0]

    def evaluate(self, s):
        """(x, y, heading, curvature) at each s (arrays); the map-wide NetworkArrays.reference evaluates alike
        (the same GeometryTable.locate and kernels)."""
        s = np.atleast_1d(np.asarray(s, dtype=float))
        if not self.geometries:
            zero = np.zeros_like(s)
            return zero, zero.copy(), zero.copy(), zero.copy()
        index = self.geometry_index(s)
        return self.table.evaluate(index, s - self.table.s[index])

    def xy(self, s) -> np.ndarray:
        x, y, _, _ = self.evaluate(s)
        return np.column_stack([x, y])
