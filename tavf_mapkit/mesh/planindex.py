"""Which triangles lie under which plan-view points: a uniform grid hash in numpy.

Road triangles are small and evenly spread, so a grid beats an R-tree here: binning and lookups are a few
sorts and searchsorted calls for hundreds of thousands of points, with no per-query overhead.
"""

from __future__ import annotations

import numpy as np


class PlanIndex:
    """Grid of the plan-view bounding boxes of triangles (``plan``: (M, 3, 2)), grown by ``pad`` metres:
    every point within ``pad`` of a triangle finds it in its own cell."""

    def __init__(self, plan: np.ndarray, pad: float = 1e-3, cell: float | None = None):
        self.plan = np.asarray(plan, dtype=float)
        self.pad = pad
        self.box_low, self.box_high = self.plan.min(axis=1), self.plan.max(axis=1)
        low, high = self.box_low - pad, self.box_high + pad
        if cell is None:
            extent = np.max(high - low, axis=1)
            cell = float(np.clip(np.median(extent), 0.25, 50.0)) if len(extent) else 1.0
        self.cell = cell
        self.origin = low.min(axis=0) if len(low) else np.zeros(2)
        i0, j0 = self._cell(low).T
        i1, j1 = self._cell(high).T
        ni, nj = i1 - i0 + 1, j1 - j0 + 1
        count = ni * nj
        triangle = np.repeat(np.arange(len(self.plan)), count)
        k = np.arange(len(triangle)) - np.repeat(np.cumsum(count) - count, count)
        ci = np.repeat(i0, count) + k % np.repeat(ni, count)
        cj = np.repeat(j0, count) + k // np.repeat(ni, count)
        key = self._key(ci, cj)
        order = np.argsort(key, kind="stable")
        self.keys, self.triangles = key[order], triangle[order]
        self._edge_lines()

    def _cell(self, xy: np.ndarray) -> np.ndarray:
        return np.floor((xy - self.origin) / self.cell).astype(np.int64)

    @staticmethod
    def _key(i: np.ndarray, j: np.ndarray) -> np.ndarray:
        return (i + (1 << 20)) * (1 << 21) + (j + (1 << 20))

    def candidates(self, points: np.ndarray):
        """(point index, triangle index) pairs whose grown boxes share the point's cell."""
        points = np.asarray(points, dtype=float)
        base = self._cell(points)
        key = self._key(base[:, 0], base[:, 1])
        lo = np.searchsorted(self.keys, key, side="left")
        hi = np.searchsorted(self.keys, key, side="right")
        count = hi - lo
        point = np.repeat(np.arange(len(points)), count)
        k = np.arange(len(point)) - np.repeat(np.cumsum(count) - count, count)
        return point, self.triangles[np.repeat(lo, count) + k]

    def covering(self, points: np.ndarray, tolerance: float | None = None):
        """(point index, triangle index) of triangles that contain a point or pass within ``tolerance``
        (at most ``pad``, the default) of it -- measured to each edge line and to the triangle's box, so a
        little more near sharp corners. A pure question of geometry: the grid only finds the candidates, so
        the answer for a point never depends on which other triangles the index holds."""
        tolerance = self.pad if tolerance is None else min(tolerance, self.pad)
        points = np.asarray(points, dtype=float)
        point, triangle = self.candidates(points)
        if not len(point):
            return point, triangle
        # the box first: most candidates of a cell lie outside it, and only the rest need their three edge lines
        px, py = points[point, 0], points[point, 1]
        low, high = self.box_low[triangle], self.box_high[triangle]
        in_box = ((px >= low[:, 0] - tolerance) & (px <= high[:, 0] + tolerance)
                  & (py >= low[:, 1] - tolerance) & (py <= high[:, 1] + tolerance))
        point, triangle, px, py = point[in_box], triangle[in_box], px[in_box, None], py[in_box, None]
        distance = self.normal_x[triangle] * px + self.normal_y[triangle] * py - self.offset[triangle]
        inside = np.all(distance >= -tolerance, axis=1)
        return point[inside], triangle[inside]

    def _edge_lines(self) -> None:
        """Inward unit normal and offset of every edge line: signed distance = n . p - offset."""
        a = self.plan
        b = self.plan[:, [1, 2, 0]]
        edge = b - a
        area2 = edge[:, 0, 0] * edge[:, 2, 1] * -1 + edge[:, 0, 1] * edge[:, 2, 0]  # cross(b - a, c - a)
        orientation = np.where(area2 < 0, -1.0, 1.0)[:, None]
        length = np.sqrt(edge[:, :, 0] ** 2 + edge[:, :, 1] ** 2)
        with np.errstate(divide="ignore", invalid="ignore"):
            nx = np.where(length > 0, -edge[:, :, 1] * orientation / length, 0.0)
            ny = np.where(length > 0, edge[:, :, 0] * orientation / length, 0.0)
        # a zero-length edge has no line: an offset of +inf makes its triangle contain nothing
        self.normal_x, self.normal_y = nx, ny
        self.offset = np.where(length > 0, nx * a[:, :, 0] + ny * a[:, :, 1], np.inf)
