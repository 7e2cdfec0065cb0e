"""Nearest lanes of points: a KD-tree over the centre-line samples of a lane graph's lanes, with exact
projection onto the polyline segments next to the nearest sample.

Positions on a lane are given as ``u``: metres along the centre line in driving direction from the lane's
start, plus road ``s`` and the driving heading of the segment.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Projection:
    """Per (point, lane) pair: which lane (node index into ``LaneIndex.keys``), where, and how far."""

    point: np.ndarray     # index of the query point
    node: np.ndarray      # index into LaneIndex.keys
    distance: np.ndarray  # metres to the lane centre line
    u: np.ndarray         # metres along the lane in driving direction
    s: np.ndarray         # road s
    heading: np.ndarray   # driving direction of the centre line there (radians)
    x: np.ndarray         # the projected point
    y: np.ndarray


class LaneIndex:
    """Build once per lane graph; query many points at once."""

    def __init__(self, graph):
        table = graph._table
        keys = sorted(graph.keys)
        row_of = np.array([graph.row(k) for k in keys], dtype=np.int64)
        node_of_row = np.full(len(table.length), -1, dtype=np.int64)
        node_of_row[row_of] = np.arange(len(keys))
        sample_row, sample_s, sample_xy = graph.samples()  # the graph's lanes only
        self.keys = keys
        self.node = node_of_row[sample_row]
        self.s = sample_s
        self.xy = sample_xy
        self.forward = np.array([graph.drives_with_s(k) for k in keys], dtype=bool)
        self.length = table.length[row_of]
        # arc length from the section start (s direction) at each sample
        step = np.r_[0.0, np.linalg.norm(np.diff(self.xy, axis=0), axis=1)]
        first = np.r_[True, self.node[1:] != self.node[:-1]]
        step[first] = 0.0
        cumulative = np.cumsum(step)
        self.arc = cumulative - np.maximum.accumulate(np.where(first, cumulative, 0.0))
        from scipy.spatial import cKDTree  # here: importing scipy costs a second, and only lookups need it

        self.tree = cKDTree(self.xy)

    def node_index(self, key) -> int:
        return self.keys.index(key)

    def _project(self, point: np.ndarray, sample: np.ndarray, qx: np.ndarray, qy: np.ndarray) -> Projection:
        """Project each query onto the segments before and after its sample (same lane only)."""
        n = len(self.node)
        best = None
        for offset in (-1, 0):
            a = np.clip(sample + offset, 0, n - 1)
            b = np.clip(a + 1, 0, n - 1)
            valid = (a != b) & (self.node[a] == self.node[sample]) & (self.node[b] == self.node[sample])
            d = self.xy[b] - self.xy[a]
            length2 = np.maximum(np.einsum("ij,ij->i", d, d), 1e-18)
            param = np.clip(((qx - self.xy[a, 0]) * d[:, 0] + (qy - self.xy[a, 1]) * d[:, 1]) / length2, 0.0, 1.0)
            param = np.where(valid, param, 0.0)
            a = np.where(valid, a, sample)
            b = np.where(valid, b, sample)
            px = self.xy[a, 0] + param * (self.xy[b, 0] - self.xy[a, 0])
            py = self.xy[a, 1] + param * (self.xy[b, 1] - self.xy[a, 1])
            distance = np.hypot(qx - px, qy - py)
            candidate = (distance, a, b, param, px, py)
            if best is None:
                best = candidate
            else:
                better = distance < best[0]
                best = tuple(np.where(better, new, old) for new, old in zip(candidate, best))
        distance, a, b, param, px, py = best
        a, b = a.astype(np.int64), b.astype(np.int64)
        node = self.node[sample]
        arc = self.arc[a] + param * (self.arc[b] - self.arc[a])
        s = self.s[a] + param * (self.s[b] - self.s[a])
        forward = self.forward[node]
        direction = self.xy[b] - self.xy[a]  # zero only on a lane with a single sample
        heading = np.arctan2(direction[:, 1], direction[:, 0]) + np.where(forward, 0.0, np.pi)
        heading = (heading + np.pi) % (2 * np.pi) - np.pi
        u = np.where(forward, arc, self.length[node] - arc)
        return Projection(point, node, distance, u, s, heading, px, py)

    def nearest(self, x, y, samples: int = 8) -> Projection:
        """The nearest lane centre line of every point (projections from its ``samples`` nearest samples)."""
        qx, qy = np.atleast_1d(np.asarray(x, dtype=float)), np.atleast_1d(np.asarray(y, dtype=float))
        k = min(samples, len(self.node))
        _, sample = self.tree.query(np.column_stack([qx, qy]), k=k)
        sample = np.asarray(sample).reshape(len(qx), k)
        point = np.repeat(np.arange(len(qx)), k)
        projection = self._project(point, sample.ravel(), qx[point], qy[point])
        best = np.argmin(projection.distance.reshape(len(qx), k), axis=1) + np.arange(len(qx)) * k
        return Projection(*(getattr(projection, f)[best] for f in Projection.__dataclass_fields__))

    def candidates(self, x, y, radius: float, per_point: int = 8) -> Projection:
        """Up to ``per_point`` nearest lanes within ``radius`` of every point, sorted by point then distance."""
        qx, qy = np.atleast_1d(np.asarray(x, dtype=float)), np.atleast_1d(np.asarray(y, dtype=float))
        found = self.tree.query_ball_point(np.column_stack([qx, qy]), r=radius, return_sorted=False)
        counts = np.fromiter((len(f) for f in found), dtype=np.int64, count=len(found))
        point = np.repeat(np.arange(len(qx)), counts)
        sample = np.fromiter((i for f in found for i in f), dtype=np.int64, count=int(counts.sum()))
        if not len(sample):
            empty = np.zeros(0)
            return Projection(point, sample, empty, empty, empty, empty, empty, empty)
        near = np.hypot(qx[point] - self.xy[sample, 0], qy[point] - self.xy[sample, 1])
        node = self.node[sample]
        # nearest sample per (point, lane), then the nearest lanes per point
        order = np.lexsort((near, node, point))
        point, sample, node, near = point[order], sample[order], node[order], near[order]
        first = np.r_[True, (point[1:] != point[:-1]) | (node[1:] != node[:-1])]
        point, sample, near = point[first], sample[first], near[first]
        order = np.lexsort((near, point))
        point, sample = point[order], sample[order]
        rank = np.arange(len(point)) - np.searchsorted(point, point, side="left")
        keep = rank < per_point
        projection = self._project(point[keep], sample[keep], qx[point[keep]], qy[point[keep]])
        order = np.lexsort((projection.distance, projection.point))
        return Projection(*(getattr(projection, f)[order] for f in Projection.__dataclass_fields__))
