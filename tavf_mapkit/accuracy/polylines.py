"""Sets of polylines sampled at a fixed step: the common currency of network comparison.

Every sample carries its line, a lane type and a driving heading; distances between two sets are exact
point-to-segment distances (the nearest sample found by a KD-tree, refined on the segments beside it).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy.spatial import cKDTree


@dataclass(frozen=True, eq=False)
class LineSamples:
    """Samples of many polylines, sorted by line; ``weight`` is the length each sample stands for (m)."""

    x: np.ndarray
    y: np.ndarray
    line: np.ndarray       # polyline id (consecutive samples of one line are neighbours)
    lane_type: np.ndarray  # object array: "driving", "biking", "sidewalk", ...
    heading: np.ndarray    # driving direction (radians)
    weight: np.ndarray

    def __len__(self) -> int:
        return len(self.x)

    @cached_property
    def tree(self) -> cKDTree:
        return cKDTree(np.column_stack([self.x, self.y]))

    def subset(self, mask: np.ndarray) -> LineSamples:
        return LineSamples(self.x[mask], self.y[mask], self.line[mask], self.lane_type[mask], self.heading[mask],
                           self.weight[mask])

    @property
    def length(self) -> float:
        return float(self.weight.sum())

    def distance_from(self, x: np.ndarray, y: np.ndarray, neighbours: int = 3) -> np.ndarray:
        """Exact distance from each point to the nearest of these polylines (segments beside the nearest
        ``neighbours`` samples)."""
        if not len(self.x):
            return np.full(len(x), np.inf)
        k = min(neighbours, len(self.x))
        _, index = self.tree.query(np.column_stack([x, y]), k=k)
        index = np.asarray(index).reshape(len(x), k)
        best = np.full(len(x), np.inf)
        n = len(self.x)
        for column in range(k):
            sample = index[:, column]
            for offset in (-1, 0):
                a = np.clip(sample + offset, 0, n - 1)
                b = np.clip(a + 1, 0, n - 1)
                same = (self.line[a] == self.line[b]) & (a != b)
                b = np.where(same, b, a)
                dx, dy = self.x[b] - self.x[a], self.y[b] - self.y[a]
                length2 = np.maximum(dx * dx + dy * dy, 1e-18)
                u = np.clip(((x - self.x[a]) * dx + (y - self.y[a]) * dy) / length2, 0.0, 1.0)
                best = np.minimum(best, np.hypot(x - self.x[a] - u * dx, y - self.y[a] - u * dy))
        return best


def resample_polylines(xy: np.ndarray, line: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Points every <= ``step`` metres along each polyline (both ends kept), vectorised over all lines.

    ``xy`` (n, 2) vertices grouped by ``line`` (sorted). Returns (points (m, 2), line of each point).
    """
    if not len(xy):
        return np.zeros((0, 2)), np.zeros(0, dtype=np.int64)
    segment = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    same = line[1:] == line[:-1]
    segment = np.where(same, segment, 0.0)
    cumulative = np.r_[0.0, np.cumsum(segment)]
    lines, first = np.unique(line, return_index=True)
    last = np.r_[first[1:], len(line)] - 1
    start, end = cumulative[first], cumulative[last]
    counts = np.maximum(np.ceil((end - start) / step - 1e-9).astype(np.int64), 1) + 1
    owner = np.repeat(np.arange(len(lines)), counts)
    k = np.arange(int(counts.sum())) - np.repeat(np.cumsum(counts) - counts, counts)
    position = start[owner] + (end - start)[owner] * k / (counts[owner] - 1)
    # global cumulative arc -> vertex index; ties at shared arc values resolve inside the owner's range
    vertex = np.searchsorted(cumulative, position, side="right") - 1
    vertex = np.clip(vertex, first[owner], np.maximum(last[owner] - 1, first[owner]))
    nxt = np.minimum(vertex + 1, last[owner])
    span = cumulative[nxt] - cumulative[vertex]
    fraction = np.where(span > 0, (position - cumulative[vertex]) / np.where(span > 0, span, 1.0), 0.0)
    points = xy[vertex] + fraction[:, None] * (xy[nxt] - xy[vertex])
    return points, lines[owner]


def line_headings(x: np.ndarray, y: np.ndarray, line: np.ndarray) -> np.ndarray:
    """Direction of each sample's polyline (towards the next sample; the last one looks back)."""
    n = len(x)
    if n == 0:
        return np.zeros(0)
    nxt = np.minimum(np.arange(n) + 1, n - 1)
    prv = np.maximum(np.arange(n) - 1, 0)
    forward_ok = (line[nxt] == line) & (nxt != np.arange(n))
    a = np.where(forward_ok, np.arange(n), prv)
    b = np.where(forward_ok, nxt, np.arange(n))
    return np.arctan2(y[b] - y[a], x[b] - x[a])


def sample_weights(x: np.ndarray, y: np.ndarray, line: np.ndarray) -> np.ndarray:
    """Length represented by each sample: half of each adjacent segment of the same line."""
    n = len(x)
    if n == 0:
        return np.zeros(0)
    segment = np.hypot(np.diff(x), np.diff(y))
    segment = np.where(line[1:] == line[:-1], segment, 0.0)
    return 0.5 * (np.r_[segment, 0.0] + np.r_[0.0, segment])
