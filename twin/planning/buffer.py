"""Per-vehicle dense paths in fixed-size arrays, so projection and look-ahead are vectorised over a fleet.

Row i holds vehicle i's path ahead (and a little behind): points about 1 m apart, their arc length ``s``,
the allowed speed ``vmax`` (speed limit and the curvature limit sqrt(a_lat / kappa)) and the lane code.
Routes arrive as chunks from an iterator per vehicle and are pulled in while less than ``horizon`` metres
lie ahead; consumed points are shifted out. A chunk that ``begins`` after a turnaround or restart does not
join the path: the path ends there (the car stops at its end), the chunk waits in ``pending`` until the
fleet moves the car onto it (``jump``).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from twin.planning.chunks import PathChunk

CURVATURE_SPAN = 2.0  # m either side over which heading change gives the curvature
JOIN_GAP = 0.25  # m: a chunk starting farther than this to the side of the path's end is joined by a blend
JOIN_PER_GAP = 4.0  # the blend replaces this many metres of path per metre of sideways gap on each side...
JOIN_MIN, JOIN_MAX = 2.0, 10.0  # ...within these bounds
KEEP_BEHIND = 16  # points kept behind the vehicle when shifting
# m: the blend's diagonal lies inside the lanes it leaves only where the path it replaces runs straight: no
# point of that path farther than this from the chord it replaces. Munich: a hairpin left turn whose last
# connecting lane ends 4.3 m beside the next road (netconvert's 0.12 m connector between two cluster junctions
# lies elsewhere) asked for 20 m of blend; cut back through the 7.8 m connector, a 7.4 m road and into the
# 130-degree turn before them, the diagonal left that turn across its inner curb
JOIN_BOW = 0.25


def join_gap(end: np.ndarray, heading: float, start: np.ndarray) -> tuple[float, float]:
    """(ahead, aside): where a chunk starting at ``start`` lies from a path ending at ``end`` with
    ``heading``, metres along the heading (negative: behind the end) and across it."""
    dx, dy = float(start[0] - end[0]), float(start[1] - end[1])
    c, s = math.cos(heading), math.sin(heading)
    return c * dx + s * dy, abs(c * dy - s * dx)


def join_cut(ahead: float, aside: float) -> float:
    """Metres of path before a chunk starting ``ahead`` metres beyond the path's end and ``aside`` metres to
    its side that the blend replaces with a diagonal. None where the straight from the end to the chunk is no
    jump: in line (sub-metre lanes stepped over leave a gap straight ahead; a diagonal from metres back would
    cut the bend before it) or at most 45 degrees off (the diagonal of a lane change, laid out by
    ``route_spans``). A sideways jump (a lane merging into its neighbour, a kink between roads) is crossed
    like a lane change, over more path the wider it is; a chunk starting behind the end (a connecting lane
    that begins before its road ends) also takes back the path it overlaps."""
    if (aside <= JOIN_GAP and ahead >= 0.0) or ahead >= aside:
        return 0.0
    return 2.0 * float(np.clip(JOIN_PER_GAP * aside, JOIN_MIN, JOIN_MAX)) - ahead


def straight_cut(points: np.ndarray, along: np.ndarray, cut: float) -> float:
    """The part of ``cut`` (m) that a blend may replace at the end of a path (``points`` (n, 2), ``along`` their
    arc length): back to the farthest point from which the path runs straight to its end (every point within
    ``JOIN_BOW`` of the chord from there to the end). The blend then starts at a point of the path, so what it
    replaces is exactly ``along[-1] - along[k]``."""
    n = len(points)
    if cut <= 0.0 or n < 2:
        return max(cut, 0.0)
    first = max(int(np.searchsorted(along, along[-1] - cut, side="right")) - 1, 0)
    tail = points[first:]
    end = tail[-1]
    chord = end[None, :] - tail  # from each candidate start k to the end
    length = np.maximum(np.hypot(chord[:, 0], chord[:, 1]), 1e-9)
    # distance of every point j >= k from the chord k -> end (rows k, columns j)
    rel = tail[None, :, :] - tail[:, None, :]
    distance = np.abs(chord[:, None, 0] * rel[:, :, 1] - chord[:, None, 1] * rel[:, :, 0]) / length[:, None]
    later = np.arange(len(tail))[None, :] >= np.arange(len(tail))[:, None]
    bow = np.where(later, distance, 0.0).max(axis=1)
    bad = np.flatnonzero(bow > JOIN_BOW)
    k = first if not len(bad) else first + int(bad[-1]) + 1  # straight from k on, back no farther than cut
    return float(min(cut, along[-1] - along[min(k, n - 1)]))


@dataclass(frozen=True, eq=False)
class Projection:
    index: np.ndarray  # segment index per vehicle
    s: np.ndarray  # arc length of the projected point
    lateral: np.ndarray  # signed distance to the path, positive = vehicle left of the path
    heading: np.ndarray  # path heading at the projection
    z: np.ndarray  # path height at the projection


class PathBuffer:
    def __init__(self, count: int, capacity: int = 4096, horizon: float = 300.0, lateral_accel: float = 2.5,
                 window: int = 24):
        self.capacity = capacity
        self.horizon = horizon
        self.lateral_accel = lateral_accel
        self.window = window
        shape = (count, capacity)
        self.x, self.y, self.z = np.zeros(shape), np.zeros(shape), np.zeros(shape)
        self.s, self.vmax = np.zeros(shape), np.zeros(shape)
        self.lane = np.zeros(shape, dtype=np.int64)
        self.count = np.zeros(count, dtype=np.int64)
        self.base = np.zeros(count, dtype=np.int64)
        self.sources: list[Iterator[PathChunk] | None] = [None] * count
        self.exhausted = np.zeros(count, dtype=bool)
        self.pending: list[PathChunk | None] = [None] * count
        self.queued: list[list[PathChunk]] = [[] for _ in range(count)]  # pieces of a chunk too long to fit
        self.waiting = np.zeros(count, dtype=bool)  # the path ends at a turnaround or restart
        self._rows = np.arange(count)

    # ------------------------------------------------------------------ filling
    def assign(self, i: int, source: Iterator[PathChunk]) -> None:
        """Give vehicle i a new route (its old path is dropped)."""
        self.sources[i] = source
        self.count[i] = 0
        self.base[i] = 0
        self.exhausted[i] = False
        self.pending[i] = None
        self.waiting[i] = False
        self.queued[i] = []
        self.refill(i)

    def jump(self, i: int) -> str:
        """Drop vehicle i's path and go on with the chunk waiting after its end; returns its ``begins``."""
        chunk = self.pending[i]
        self.pending[i] = None
        self.waiting[i] = False
        self.count[i] = 0
        self.base[i] = 0
        self._append(i, chunk)
        self.refill(i)
        return chunk.begins

    def remaining(self, i: int) -> float:
        if self.count[i] == 0:
            return 0.0
        return float(self.s[i, self.count[i] - 1] - self.s[i, self.base[i]])

    def refill(self, i: int) -> None:
        while not self.exhausted[i] and not self.waiting[i] and self.remaining(i) < self.horizon:
            chunk = self._next_chunk(i)
            if chunk is None:
                self.exhausted[i] = True
                if self.count[i]:
                    self.vmax[i, self.count[i] - 1] = 0.0  # stop at the end of a finite route
                break
            if chunk.begins is not None and self.count[i]:
                self.pending[i] = chunk
                self.waiting[i] = True
                self.vmax[i, self.count[i] - 1] = 0.0  # stop where the path ends
                break
            self._append(i, chunk)

    def refill_all(self) -> None:
        """Top up every row whose path ahead has become short (cheap check first)."""
        n = self.count
        last = self.s[self._rows, np.maximum(n - 1, 0)]
        short = (last - self.s[self._rows, self.base] < 0.5 * self.horizon) & ~self.exhausted & ~self.waiting
        for i in np.flatnonzero(short):
            self.refill(int(i))

    def _next_chunk(self, i: int) -> PathChunk | None:
        """The next chunk of vehicle i's route; one longer than a quarter of the capacity (a lane of
        kilometres) comes in pieces that share their end points, so the path never has to be cut."""
        if self.queued[i]:
            return self.queued[i].pop(0)
        chunk = next(self.sources[i], None)
        piece = self.capacity // 4
        if chunk is None or len(chunk) <= piece:
            return chunk
        starts = range(0, len(chunk) - 1, piece)
        pieces = [chunk.slice(max(k - 1, 0), k + piece) for k in starts]
        self.queued[i] = [PathChunk(p.points, p.speed_limit, p.lane_code) for p in pieces[1:]]
        return pieces[0]

    def _append(self, i: int, chunk: PathChunk) -> None:
        points = chunk.points
        n = int(self.count[i])
        if n and len(points):
            gap = float(np.hypot(points[0, 0] - self.x[i, n - 1], points[0, 1] - self.y[i, n - 1]))
            if gap < 1e-3:
                chunk = chunk.slice(1)
            elif gap > JOIN_GAP:
                end = (self.x[i, n - 1], self.y[i, n - 1])
                before = (self.x[i, n - 2], self.y[i, n - 2]) if n > 1 else end
                heading = math.atan2(end[1] - before[1], end[0] - before[0]) if n > 1 else \
                    math.atan2(points[0, 1] - end[1], points[0, 0] - end[0])
                cut = join_cut(*join_gap(np.array(end), heading, points[0]))
                if cut > 0.0:
                    self._blend(i, cut)
                    n = int(self.count[i])  # the blend shortened the path: the chunk joins where it now ends
            points = chunk.points
        if not len(points):
            return
        if n + len(points) > self.capacity:
            self._shift(i)
            n = int(self.count[i])
            if n + len(points) > self.capacity:
                chunk = chunk.slice(0, self.capacity - n)
                points = chunk.points
        m = n + len(points)
        self.x[i, n:m], self.y[i, n:m], self.z[i, n:m] = points[:, 0], points[:, 1], points[:, 2]
        self.lane[i, n:m] = chunk.lane_code
        start = self.s[i, n - 1] if n else 0.0
        previous = (self.x[i, n - 1], self.y[i, n - 1]) if n else (points[0, 0], points[0, 1])
        steps = np.hypot(np.diff(np.concatenate([[previous[0]], points[:, 0]])),
                         np.diff(np.concatenate([[previous[1]], points[:, 1]])))
        self.s[i, n:m] = start + np.cumsum(steps)
        self.vmax[i, n:m] = chunk.speed_limit
        self.count[i] = m
        self._curvature_limit(i, max(n - 8, 0), m)

    def _blend(self, i: int, cut: float) -> None:
        """Where lane ends do not meet (a lane merging into its neighbour, a kink between roads), drop the
        last ``cut`` metres (``join_cut``) of the path not yet reached, so the path crosses over to the next
        chunk's start on a straight diagonal like a lane change, inside the lanes it leaves, instead of
        jumping sideways. Only path that runs straight is replaced (``straight_cut``): a diagonal across a
        bend would leave its lanes."""
        n = int(self.count[i])
        keep_until = min(int(self.base[i]) + 2, n)
        lo = int(self.base[i])
        cut = straight_cut(np.column_stack([self.x[i, lo:n], self.y[i, lo:n]]), self.s[i, lo:n], cut)
        kept = int(np.searchsorted(self.s[i, :n], self.s[i, n - 1] - cut + 1e-9, side="right"))
        self.count[i] = max(kept, keep_until, 1)

    def _shift(self, i: int) -> None:
        drop = int(max(self.base[i] - KEEP_BEHIND, 0))
        if drop == 0:
            return
        n = int(self.count[i])
        for array in (self.x, self.y, self.z, self.s, self.vmax, self.lane):
            array[i, : n - drop] = array[i, drop:n]
        self.count[i] = n - drop
        self.base[i] -= drop

    def _curvature_limit(self, i: int, start: int, stop: int) -> None:
        """Lower vmax of points start..stop to sqrt(a_lat / kappa), kappa from heading change over +-2 m."""
        lo = max(start - 8, 0)
        n = int(self.count[i])
        x, y, s = self.x[i, lo:n], self.y[i, lo:n], self.s[i, lo:n]
        if len(x) < 3:
            return
        seg = np.hypot(np.diff(x), np.diff(y))
        heading = np.arctan2(np.diff(y), np.diff(x))
        valid = seg > 1e-3
        # zero-length segments take the heading of the last real one
        index = np.maximum.accumulate(np.where(valid, np.arange(len(seg)), 0))
        heading = np.unwrap(heading[index])
        q = s[start - lo:stop - lo]
        middle = 0.5 * (s[1:] + s[:-1])  # arc length of each segment's midpoint

        def segment_at(sq):
            return np.clip(np.searchsorted(s, sq, side="right") - 1, 0, len(heading) - 1)

        before, after = segment_at(q - CURVATURE_SPAN), segment_at(q + CURVATURE_SPAN)
        span = np.maximum(middle[after] - middle[before], 1e-3)
        kappa = np.where(after > before, np.abs(heading[after] - heading[before]) / span, 0.0)
        limit = np.sqrt(self.lateral_accel / np.maximum(kappa, 1e-6))
        self.vmax[i, start:stop] = np.minimum(self.vmax[i, start:stop], limit)

    # ------------------------------------------------------------------ queries
    def skip(self, mask: np.ndarray, distance: float) -> None:
        """Move the masked paths' position ``distance`` metres ahead: past an obstacle standing on the path."""
        for i in np.flatnonzero(mask):  # only the vehicles that just hit something
            self.refill(i)
            n = int(self.count[i])
            target = self.s[i, self.base[i]] + distance
            self.base[i] = min(int(np.searchsorted(self.s[i, :n], target)), max(n - 2, 0))

    def _gather(self, array: np.ndarray, index: np.ndarray) -> np.ndarray:
        return array[self._rows[:, None], index]

    def project(self, x: np.ndarray, y: np.ndarray) -> Projection:
        """Nearest point on each path within ``window`` segments ahead of the last projection; advances ``base``."""
        last_segment = np.maximum(self.count - 2, 0)
        index = np.minimum(self.base[:, None] + np.arange(self.window)[None, :], last_segment[:, None])
        ax, ay = self._gather(self.x, index), self._gather(self.y, index)
        dx, dy = self._gather(self.x, index + 1) - ax, self._gather(self.y, index + 1) - ay
        length_sq = np.maximum(dx * dx + dy * dy, 1e-12)
        px, py = x[:, None] - ax, y[:, None] - ay
        f = np.clip((px * dx + py * dy) / length_sq, 0.0, 1.0)
        ex, ey = px - f * dx, py - f * dy
        best = np.argmin(ex * ex + ey * ey, axis=1)
        r = self._rows
        segment = index[r, best]
        self.base = segment
        fb, dxb, dyb = f[r, best], dx[r, best], dy[r, best]
        length = np.sqrt(length_sq[r, best])
        lateral = (dxb * py[r, best] - dyb * px[r, best]) / length
        s = self.s[r, segment] + fb * (self.s[r, segment + 1] - self.s[r, segment])
        z = self.z[r, segment] + fb * (self.z[r, segment + 1] - self.z[r, segment])
        return Projection(segment, s, lateral, np.arctan2(dyb, dxb), z)

    def point_at(self, s_target: np.ndarray, window: int = 64) -> tuple[np.ndarray, np.ndarray]:
        """(x, y) at arc length ``s_target`` (clamped to the path's end)."""
        last = np.maximum(self.count - 1, 0)
        index = np.minimum(self.base[:, None] + np.arange(window)[None, :], last[:, None])
        s = self._gather(self.s, index)
        k = np.clip((s < s_target[:, None]).sum(axis=1), 1, window - 1)
        r = self._rows
        i1, i0 = index[r, k], index[r, k - 1]
        span = self.s[r, i1] - self.s[r, i0]
        f = np.where(span > 1e-9, np.clip((s_target - self.s[r, i0]) / np.where(span > 1e-9, span, 1.0), 0, 1), 1.0)
        return (self.x[r, i0] + f * (self.x[r, i1] - self.x[r, i0]),
                self.y[r, i0] + f * (self.y[r, i1] - self.y[r, i0]))

    def allowed_speed(self, s_now: np.ndarray, decel: float, window: int = 160) -> np.ndarray:
        """The highest speed from which every vmax ahead is reachable braking at ``decel``."""
        last = np.maximum(self.count - 1, 0)
        index = np.minimum(self.base[:, None] + np.arange(window)[None, :], last[:, None])
        distance = np.maximum(self._gather(self.s, index) - s_now[:, None], 0.0)
        vmax = self._gather(self.vmax, index)
        return np.sqrt(np.min(vmax * vmax + 2.0 * decel * distance, axis=1))

    def at_end(self, s_now: np.ndarray, margin: float = 1.0) -> np.ndarray:
        """True for vehicles whose finite route is driven to its end."""
        last = self.s[self._rows, np.maximum(self.count - 1, 0)]
        return self.exhausted & (s_now >= last - margin)

    def at_break(self, s_now: np.ndarray, margin: float = 1.0) -> np.ndarray:
        """True for vehicles at the end of a path that goes on after a turnaround or restart."""
        last = self.s[self._rows, np.maximum(self.count - 1, 0)]
        return self.waiting & (s_now >= last - margin)

    def lane_code(self, projection: Projection) -> np.ndarray:
        return self.lane[self._rows, projection.index]

    def path_ahead(self, i: int, distance: float) -> np.ndarray:
        """(n, 3) path points of vehicle i from its projection on, up to ``distance`` metres."""
        b, n = int(self.base[i]), int(self.count[i])
        stop = b + int(np.searchsorted(self.s[i, b:n], self.s[i, b] + distance, side="right"))
        return np.column_stack([self.x[i, b:stop], self.y[i, b:stop], self.z[i, b:stop]])
