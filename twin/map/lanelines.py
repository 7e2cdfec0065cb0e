"""Lane centre lines in driving direction with arc length, computed once per lane and cached."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tavf_mapkit.lanegraph import LaneGraph, LaneKey


@dataclass(frozen=True, eq=False)
class LaneLine:
    key: LaneKey
    points: np.ndarray  # (n, 3) in driving direction, at most ``step`` apart
    along: np.ndarray  # (n,) arc length from the lane's entry, metres
    speed_limit: float | None

    @property
    def length(self) -> float:
        return float(self.along[-1])

    def at(self, along: float) -> tuple[np.ndarray, float]:
        """(x, y, z) and heading at a distance along the lane (clamped to the lane)."""
        a = float(np.clip(along, 0.0, self.length))
        i = int(np.clip(np.searchsorted(self.along, a, side="right") - 1, 0, max(len(self.along) - 2, 0)))
        if len(self.along) < 2:
            return self.points[0].copy(), 0.0
        span = self.along[i + 1] - self.along[i]
        f = 0.0 if span <= 0 else (a - self.along[i]) / span
        point = self.points[i] + f * (self.points[i + 1] - self.points[i])
        d = self.points[i + 1] - self.points[i]
        return point, float(np.arctan2(d[1], d[0]))


class LaneLines:
    """Centre lines of a lane graph's lanes, built on first use."""

    def __init__(self, graph: LaneGraph, step: float = 1.0):
        self.graph = graph
        self.step = step
        self._cache: dict[LaneKey, LaneLine] = {}

    def __getitem__(self, key: LaneKey) -> LaneLine:
        line = self._cache.get(key)
        if line is None:
            points, _ = self.graph.centerline(key, self.step)
            along = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points[:, :2], axis=0), axis=1))])
            line = LaneLine(key, points, along, self.graph.speed_limit(key))
            self._cache[key] = line
        return line
