"""Lane centre lines in driving direction with arc length, computed once per lane and cached.

Where a lane lies farther from its road's reference line than the line's radius of curvature (outer lanes
on the inside of netconvert's tight bends and junction corners), its offset centre line folds back on
itself: a small loop ("swallowtail") or a zig-zag, metres long on lanes that are otherwise straight. No car
drives such a loop, so each line is cut at its self-intersections (``without_loops``), leaving the kink a
driver actually follows. A fold that the lane's end cuts open (no crossing left inside the lane) or that
doubles back on itself without crossing shows as a cusp, a reversal between two segments; the part of
the line before (after) a cusp near the start (end) is dropped, a cusp inside loses its vertex
(``without_folds``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from tavf_mapkit.lanegraph import LaneGraph, LaneKey
from tavf_mapkit.mesh.exact import run_cumsum


@dataclass(frozen=True, eq=False, slots=True)  # slots: a region's start holds one per lane (161,781 on Columbus)
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


#: centre-line points evaluated and measured at once (a lane centre costs ~400 bytes through the evaluator)
BATCH_POINTS = 500_000
LOOP_WINDOW = 40  # samples: a fold is shorter than this (its size is about the lane's offset)
CUSP = np.radians(120.0)  # a turn this sharp between two consecutive segments is a fold, not a corner
FOLD_END = 5.0  # m: a cusp this close to an end cuts the rest of the line off towards that end


def without_loops(points: np.ndarray, window: int = LOOP_WINDOW) -> np.ndarray:
    """The polyline (n, 3) with every loop cut out: where segment i crosses a later segment j (at most
    ``window`` segments on, in plan view), the points between them are replaced by the crossing point
    (the outermost crossing of each i; height interpolated along segment i)."""
    return lines_without_loops([points], window)[0]


def lines_without_loops(lines: list[np.ndarray], window: int = LOOP_WINDOW) -> list[np.ndarray]:
    """``without_loops`` of many polylines, their crossings found in one pass per gap (every crossing test
    is one pair of segments of one line: the same lines, to the bit)."""
    lines = list(lines)
    may_cross = [k for k, points in enumerate(lines) if _turns_half_a_circle(points)]
    if not may_cross:
        return lines
    segments = [lines[k][:, :2] for k in may_cross]
    a = np.concatenate([p[:-1] for p in segments])
    d = np.concatenate([np.diff(p, axis=0) for p in segments])
    counts = np.array([len(p) - 1 for p in segments])
    owner = np.repeat(np.arange(len(segments)), counts)
    first = np.cumsum(counts) - counts
    found_owner, found_i, found_j, found_f = [], [], [], []
    for gap in range(2, window + 1):
        i = np.arange(len(owner) - gap)
        i = i[owner[i] == owner[i + gap]]  # both segments on one line (gap < its segment count)
        if not len(i):
            break
        j = i + gap
        denominator = d[i, 0] * d[j, 1] - d[i, 1] * d[j, 0]
        r = a[j] - a[i]
        safe = np.where(np.abs(denominator) > 1e-12, denominator, 1.0)
        f = (r[:, 0] * d[j, 1] - r[:, 1] * d[j, 0]) / safe  # along segment i
        g = (r[:, 0] * d[i, 1] - r[:, 1] * d[i, 0]) / safe  # along segment j
        hit = (np.abs(denominator) > 1e-12) & (f >= 0) & (f <= 1) & (g >= 0) & (g <= 1)
        found_owner.append(owner[i[hit]])
        found_i.append(i[hit] - first[owner[i[hit]]])
        found_j.append(j[hit] - first[owner[i[hit]]])
        found_f.append(f[hit])
    if not found_owner:
        return lines
    owner, i, j, f = (np.concatenate(x) for x in (found_owner, found_i, found_j, found_f))
    order = np.argsort(owner, kind="stable")
    owner, i, j, f = owner[order], i[order], j[order], f[order]
    bounds = np.searchsorted(owner, np.arange(len(segments) + 1))
    for line, (lo, hi) in enumerate(zip(bounds[:-1].tolist(), bounds[1:].tolist())):
        if hi > lo:
            k = may_cross[line]
            lines[k] = _cut_loops(lines[k], i[lo:hi], j[lo:hi], f[lo:hi])
    return lines


def _turns_half_a_circle(points: np.ndarray) -> bool:
    """A line must turn by half a circle at least to cross itself (and have 3 segments)."""
    if len(points) - 1 < 3:
        return False
    d = np.diff(points[:, :2], axis=0)
    heading = np.arctan2(d[:, 1], d[:, 0])
    return not np.sum(np.abs((np.diff(heading) + np.pi) % (2 * np.pi) - np.pi)) < np.pi


def _cut_loops(points: np.ndarray, i: np.ndarray, j: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Cut the loops between crossing segments i < j (at fraction f of segment i) out of one line."""
    pieces, done = [], 0
    for first in np.unique(i):  # in order along the line; loops inside a cut loop are gone with it
        if first < done:
            continue
        k = np.flatnonzero(i == first)
        k = k[np.argmax(j[k])]
        pieces.append(points[done:first + 1])
        pieces.append((points[first] + f[k] * (points[first + 1] - points[first]))[None, :])
        done = int(j[k]) + 1
    pieces.append(points[done:])
    return np.concatenate(pieces)


def without_folds(points: np.ndarray) -> np.ndarray:
    """The polyline (n, 3) without cusps (see the module docstring). Repeated points are dropped."""
    for _ in range(len(points)):  # every pass removes at least one point
        step = np.hypot(*np.diff(points[:, :2], axis=0).T)
        points = points[np.r_[True, step > 1e-9]]
        d = np.diff(points[:, :2], axis=0)
        if len(d) < 2:
            return points
        heading = np.arctan2(d[:, 1], d[:, 0])
        turn = np.abs((np.diff(heading) + np.pi) % (2 * np.pi) - np.pi)
        cusps = np.flatnonzero(turn > CUSP)
        if not len(cusps):
            return points
        vertex = int(cusps[0]) + 1
        along = np.r_[0.0, np.cumsum(np.hypot(d[:, 0], d[:, 1]))]
        if along[vertex] <= FOLD_END:
            points = points[vertex:]
        elif along[-1] - along[vertex] <= FOLD_END:
            points = points[:vertex + 1]
        else:
            points = np.delete(points, vertex, axis=0)
    return points


@dataclass(frozen=True, eq=False, slots=True)
class LaneEnds:
    """A lane's length and, in plan view, the points of its first and last metres with their arc length from
    the lane's entry (the whole line's values, to the bit): ``head`` every point within ``ENDS_HEAD`` m of
    the entry, ``tail`` every point within ``ENDS_TAIL`` m of the exit and the last one before them, each at
    least two points (of lines with two). ``whole``: both are the whole line."""

    length: float
    head: np.ndarray  # (h, 2)
    head_along: np.ndarray  # (h,)
    tail: np.ndarray  # (t, 2)
    tail_along: np.ndarray  # (t,)
    whole: bool

    @classmethod
    def of(cls, line: LaneLine) -> LaneEnds:
        return cls(line.length, line.points[:, :2], line.along, line.points[:, :2], line.along, True)

    def tail_from(self, along: float) -> bool:
        """Does ``tail`` hold every point from ``along`` (m from the entry) on, and the last one before?"""
        return self.whole or along >= self.length - ENDS_TAIL


#: m of a lane's entry and exit kept for route selection (``LaneLines.scan``): what ``twin.planning.drivable``
#: measures of a step between lanes (its REACH of 8 m, and at the exit up to 8 m a join's blend replaces)
ENDS_HEAD, ENDS_TAIL = 8.0, 16.0


class EndsArrays(NamedTuple):
    """``LaneEnds`` of many lanes: lane ``index[key]``'s head is ``head[head_at[i]:head_at[i + 1]]`` (and
    ``head_along``), its tail ``tail[tail_at[i]:tail_at[i + 1]]``, its length ``length[i]``."""

    index: dict
    length: np.ndarray
    head_at: np.ndarray
    head: np.ndarray
    head_along: np.ndarray
    tail_at: np.ndarray
    tail: np.ndarray
    tail_along: np.ndarray


class LineBatch(NamedTuple):
    """Lane lines of many lanes as flat arrays (``LaneLines.scan``): lane ``i`` (``keys[i]``) is
    ``points[at[i]:at[i + 1]]`` with arc lengths ``along[at[i]:at[i + 1]]``, the numbers of its ``LaneLine``.
    A region's lanes are tens of thousands: no object and no arrays per lane."""

    keys: list
    at: np.ndarray  # (n + 1,)
    points: np.ndarray  # (m, 3)
    along: np.ndarray  # (m,)
    #: per lane the sums of its heading changes between consecutive segments (plan view, each wrapped to
    #: [-pi, pi)): signed, and of their absolute values (``drivable.total_turning``), as one sum per lane gives
    turn: np.ndarray
    turning: np.ndarray

    @property
    def length(self) -> np.ndarray:
        """Per lane its length (its last arc length; ``LaneLine.length``)."""
        return self.along[self.at[1:] - 1]

    @property
    def counts(self) -> np.ndarray:
        return np.diff(self.at)


class _EndsTable:
    """``LaneEnds`` of many lanes in a few flat arrays (a region has 161,781 lanes: an object and four arrays
    per lane would cost more than the points)."""

    def __init__(self):
        self.index: dict[LaneKey, int] = {}
        self._parts: list[tuple] = []
        self._arrays = None

    def add(self, batch: LineBatch, lanes: np.ndarray) -> None:
        """Keep the ends of the lanes ``lanes`` (positions in ``batch``, ascending)."""
        if not len(lanes):
            return
        counts = batch.counts[lanes]
        lane = np.repeat(np.arange(len(lanes)), counts)
        first = np.cumsum(counts) - counts
        taken = np.repeat(batch.at[lanes] - first, counts) + np.arange(len(lane))  # the lanes' points
        points, along = batch.points[taken, :2], batch.along[taken]
        position = np.arange(len(along)) - first[lane]
        length = batch.length[lanes]
        head = (along <= ENDS_HEAD) | (position < 2)
        # the tail: points beyond length - ENDS_TAIL, the last point at or before it, and the last two points
        limit = length[lane] - ENDS_TAIL
        beyond = along > limit
        next_beyond = np.r_[beyond[1:], False] & np.r_[lane[1:] == lane[:-1], False]
        tail = beyond | next_beyond | (position >= counts[lane] - 2)
        for i in lanes.tolist():
            self.index[batch.keys[i]] = len(self.index)
        self._parts.append((length, np.bincount(lane[head], minlength=len(lanes)), points[head], along[head],
                            np.bincount(lane[tail], minlength=len(lanes)), points[tail], along[tail]))
        self._arrays = None

    def __contains__(self, key: LaneKey) -> bool:
        return key in self.index

    def _joined(self):
        if self._arrays is None:
            length, head_n, head, head_along, tail_n, tail, tail_along = (np.concatenate(x) for x in
                                                                          zip(*self._parts))
            self._parts = [(length, head_n, head, head_along, tail_n, tail, tail_along)]
            self._arrays = (length, np.r_[0, np.cumsum(head_n)], head, head_along, np.r_[0, np.cumsum(tail_n)],
                            tail, tail_along)
            self._lengths = length.tolist()
        return self._arrays

    def length(self, key: LaneKey) -> float:
        return self.length_at(self.index[key])

    def length_at(self, i: int) -> float:
        """The length of the i-th lane added (route selection asks hundreds of thousands of times: a list)."""
        if self._arrays is None:
            self._joined()
        return self._lengths[i]

    def arrays(self) -> EndsArrays:
        """The whole table as flat arrays (``EndsArrays``), for measuring many lanes at once."""
        if not self.index:
            none, at = np.zeros(0), np.zeros(1, dtype=np.int64)
            return EndsArrays({}, none, at, np.zeros((0, 2)), none, at, np.zeros((0, 2)), none)
        return EndsArrays(self.index, *self._joined())

    def __getitem__(self, key: LaneKey) -> LaneEnds:
        length, head_at, head, head_along, tail_at, tail, tail_along = self._joined()
        i = self.index[key]
        h, t = slice(head_at[i], head_at[i + 1]), slice(tail_at[i], tail_at[i + 1])
        return LaneEnds(float(length[i]), head[h], head_along[h], tail[t], tail_along[t], False)


class LaneLines:
    """Centre lines of a lane graph's lanes, built on first use."""

    def __init__(self, graph: LaneGraph, step: float = 1.0):
        self.graph = graph
        self.step = step
        self._cache: dict[LaneKey, LaneLine] = {}
        self._ends = _EndsTable()
        self._known_lengths: dict[LaneKey, float] = {}  # lengths known without the lines (``remember_lengths``)

    def scan(self, keys):
        """The lines of ``keys`` (``LineBatch``es, lanes in order), batch by batch, not kept: a region's lines
        do not fit beside its map (Columbus: 161,781 lanes). Only their ends stay (``ends``); a line asked for
        later is built again, the same to the bit."""
        for batch in lane_batches(self.graph, list(dict.fromkeys(keys)), self.step):
            lines = self._evaluate(batch)
            # kept lines are their own ends
            new = np.fromiter((k not in self._cache and k not in self._ends for k in batch), dtype=bool,
                              count=len(batch))
            self._ends.add(lines, np.flatnonzero(new))
            yield lines

    def line(self, key: LaneKey) -> LaneLine:
        """The lane's line, not kept when it was not (a line asked for once, in the middle of a scan)."""
        line = self._cache.get(key)
        return line if line is not None else self._build([key])[0]

    def ends(self, key: LaneKey) -> LaneEnds:
        """The lane's length and the points of its first and last metres (``LaneEnds``)."""
        if key in self._ends:
            return self._ends[key]
        return LaneEnds.of(self[key])

    def ends_arrays(self) -> EndsArrays:
        """The ends kept by ``scan`` as flat arrays: the lanes scanned, not those whose lines are kept (their
        ends are ``ends(key)``)."""
        return self._ends.arrays()

    def length(self, key: LaneKey) -> float:
        """The length of the lane's line (m)."""
        i = self._ends.index.get(key)
        if i is not None:
            return self._ends.length_at(i)
        known = self._known_lengths.get(key)
        return known if known is not None else self[key].length

    def remember_lengths(self, keys, lengths) -> None:
        """Lengths of these lanes' lines, as ``length`` gave them before (a saved route plan): their lines are
        then built only when asked for."""
        self._known_lengths.update(zip(keys, lengths))

    def __getitem__(self, key: LaneKey) -> LaneLine:
        line = self._cache.get(key)
        if line is None:
            self.preload([key])
            line = self._cache[key]
        return line

    def preload(self, keys) -> None:
        """Build the lines of many lanes at once (one evaluation of the map instead of one per lane).

        ``without_loops`` and ``without_folds`` run only on the lines that may have a loop or a fold (a region
        has tens of thousands of lanes, nearly all without): the same lines, to the bit."""
        missing = list(dict.fromkeys(k for k in keys if k not in self._cache))
        for batch in lane_batches(self.graph, missing, self.step):
            self._preload(batch)

    def _preload(self, missing: list[LaneKey]) -> None:
        for line in self._build(missing):
            self._cache[line.key] = line

    def _build(self, missing: list[LaneKey]) -> list[LaneLine]:
        if not missing:
            return []
        lines = self._evaluate(missing)
        at = lines.at.tolist()
        # a line of its own, always a copy: a view (a lane driven with s) would keep the whole batch's points
        # alive, the copies of the reversed lanes beside them (Columbus: ~90 MB of lines held twice)
        return [LaneLine(key, lines.points[lo:hi].copy(), lines.along[lo:hi].copy(), self.graph.speed_limit(key))
                for key, lo, hi in zip(missing, at[:-1], at[1:])]

    def _evaluate(self, keys: list[LaneKey]) -> LineBatch:
        """The lines of ``keys`` (one evaluation of the map for all of them)."""
        if not keys:
            return LineBatch([], np.zeros(1, dtype=np.int64), np.zeros((0, 3)), np.zeros(0), np.zeros(0), np.zeros(0))
        points, _, counts = self.graph.centerline_arrays(keys, self.step)
        lane = np.repeat(np.arange(len(keys)), counts)
        turn, turning, may_change = _turns(lane, points, len(keys))
        suspect = np.flatnonzero(may_change).tolist()
        if suspect:  # (not np.any: a list [0], the first line alone, is a suspect too)
            at = np.r_[0, np.cumsum(counts)].tolist()
            fixed = [without_folds(line) for line in lines_without_loops([points[at[i]:at[i + 1]] for i in suspect])]
            pieces, done = [], 0
            for i, line in zip(suspect, fixed):  # the lines between suspects as they are, each suspect fixed
                pieces += [points[at[done]:at[i]], line]
                done = i + 1
            points = np.concatenate(pieces + [points[at[done]:]])
            counts = counts.copy()
            counts[suspect] = [len(line) for line in fixed]
            lane = np.repeat(np.arange(len(keys)), counts)
            # the fixed lines' own sums (each lane's sums are its own: the others' stay as they are)
            fixed_lane = np.repeat(np.arange(len(fixed)), [len(line) for line in fixed])
            turn[suspect], turning[suspect], _ = _turns(fixed_lane, np.concatenate(fixed), len(fixed))
        # arc length per line: each line's own sequential sum, as a cumsum of that line alone would give
        step = np.linalg.norm(np.diff(points[:, :2], axis=0), axis=1)
        along = run_cumsum(np.r_[0.0, np.where(lane[1:] == lane[:-1], step, 0.0)], lane)
        return LineBatch(list(keys), np.r_[0, np.cumsum(counts)], points, along, turn, turning)


def lane_batches(graph: LaneGraph, keys: list[LaneKey], step: float):
    """``keys`` in runs of about ``BATCH_POINTS`` centre-line points each (estimated from the lane sections'
    lengths in s, which set how many points ``centerlines`` takes: not the lanes' own lengths, which would
    sample the whole map once more before its lines), so a region's lines are evaluated and measured in bounded
    memory; every line is its own, batches or not."""
    if not keys:
        return
    arrays = graph.odr.arrays
    section = arrays.lane_section[np.array([graph.row(k) for k in keys], dtype=np.int64)]
    estimate = (arrays.section_end[section] - arrays.section_s0[section]) / step + 2.0
    batch = (np.cumsum(estimate) // BATCH_POINTS).astype(np.int64)
    cuts = np.flatnonzero(np.diff(batch)) + 1
    for lo, hi in zip(np.r_[0, cuts].tolist(), np.r_[cuts, len(keys)].tolist()):
        yield keys[lo:hi]


def _turns(lane: np.ndarray, points: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per line (runs of ``lane`` 0 .. count-1): the sum of its heading changes between consecutive segments
    (each wrapped to [-pi, pi)), the sum of their absolute values, and whether ``without_loops`` or
    ``without_folds`` may change it: a loop needs half a circle of turning, a fold a repeated point or a cusp
    (the margins make this a superset). One pass over the headings for the filters and the bends."""
    d = np.diff(points[:, :2], axis=0)
    same = lane[1:] == lane[:-1]
    repeated = same & (np.hypot(d[:, 0], d[:, 1]) <= 1e-9)
    heading = np.arctan2(d[:, 1], d[:, 0])
    wrapped = (np.diff(heading) + np.pi) % (2 * np.pi) - np.pi
    absolute = np.abs(wrapped)
    inside = same[1:] & same[:-1]
    owner = lane[1:-1][inside]
    turn = np.bincount(owner, weights=wrapped[inside], minlength=count)
    turning = np.bincount(owner, weights=absolute[inside], minlength=count)
    cusp = np.bincount(owner, weights=absolute[inside] > CUSP - 1e-6, minlength=count) > 0
    has_repeat = np.bincount(lane[1:][repeated], minlength=count) > 0
    return turn, turning, (turning >= np.pi * (1 - 1e-6)) | cusp | has_repeat
