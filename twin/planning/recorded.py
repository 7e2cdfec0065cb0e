"""Recorded routes: a GNSS trace -> map-matched lanes -> one drivable lane route -> a path at recorded speed.

The matcher (``tavf_mapkit.accuracy.matching``) gives each fix a lane and a lane route that breaks where the
recording went where no car may (a bicycle ride crosses squares, uses both sides of a dual carriageway).
A car needs one connected route, so the lanes of the matched route are taken as anchors in recording
order and chained by dynamic programming (``join_anchors``): skipping an anchor costs a fixed distance per
fix on it, reaching one costs the detour the lane graph forces. Anchors that only an illegal or absurd
manoeuvre would reach are skipped (their fixes still count in the metrics).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tavf_mapkit.errors import InputError
from tavf_mapkit.lanegraph import LaneGraph, LaneKey
from twin.map.lanelines import LaneLines
from twin.planning.chunks import DEFAULT_SPEED, LaneCodes, PathChunk, lane_chunk, route_spans

MIN_SPEED = 2.0  # m/s: a recording that stands still (traffic lights, the start) must not stop the car forever


@dataclass(frozen=True)
class Anchor:
    """A lane of the matched route with what the recording did on it: how many fixes, where along the lane
    the first and last of them lie (m), and how far along the recording they were (m)."""

    key: LaneKey
    fixes: int
    u_first: float
    u_last: float
    trace_first: float
    trace_last: float


def join_anchors(graph: LaneGraph, anchors: list[Anchor], skip_cost_m: float = 25.0, window: int = 20,
                 cutoff_m: float = 3000.0) -> tuple[list[LaneKey], list[int]]:
    """(connected lane route, route position of each anchor or -1 where skipped).

    Dynamic programming over the anchors in order: going from anchor i to a later anchor j costs how much
    the lane graph's shortest drive between their fixes differs from the distance the recording covered
    between them, plus ``skip_cost_m`` for every fix on the anchors skipped in between (also before the
    first and after the last anchor used). Anchors on the way cost nothing; anchors that only an excursion,
    a U-turn or an illegal manoeuvre would reach are skipped.
    """
    m = len(anchors)
    keys = [a.key for a in anchors]
    fixes_before = np.concatenate([[0], np.cumsum([a.fixes for a in anchors])])
    lengths, paths = [], []
    for key in keys:
        length, path = graph.routes_from(key, cutoff=cutoff_m)
        lengths.append(length)
        paths.append(path)
    best = np.full(m, np.inf)
    previous = np.full(m, -1)
    for j in range(m):
        best[j] = skip_cost_m * fixes_before[j]
        b = anchors[j]
        for i in range(max(0, j - window), j):
            a = anchors[i]
            if not np.isfinite(best[i]) or (keys[j] not in lengths[i] and keys[i] != keys[j]):
                continue
            if keys[i] == keys[j]:
                driven = b.u_first - a.u_last
            else:  # edge weights: a follow edge costs the length of the lane it leaves
                driven = lengths[i][keys[j]] - a.u_last + b.u_first
            recorded = b.trace_first - a.trace_last
            cost = best[i] + abs(driven - recorded) + skip_cost_m * (fixes_before[j] - fixes_before[i + 1])
            if cost < best[j]:
                best[j], previous[j] = cost, i
    final = best + skip_cost_m * (fixes_before[-1] - fixes_before[1:])
    chain = [int(np.argmin(final))]
    while previous[chain[-1]] >= 0:
        chain.append(int(previous[chain[-1]]))
    chain.reverse()
    route = [keys[chain[0]]]
    placed = [-1] * m
    placed[chain[0]] = 0
    for i, j in itertools.pairwise(chain):
        if keys[i] != keys[j]:
            route.extend(paths[i][keys[j]][1:])
        placed[j] = len(route) - 1
    return route, placed


def anchors_of(match) -> tuple[list[Anchor], list[int]]:
    """The matched route's lanes that carry fixes as anchors (the matcher also inserts lanes between fixes),
    and the anchor index of each entry of ``match.lane_route`` (-1 for the inserted ones)."""
    matched = np.flatnonzero(match.matched)
    step = np.hypot(np.diff(match.x), np.diff(match.y))
    along = np.concatenate([[0.0], np.cumsum(np.where(np.isfinite(step), step, 0.0))])
    out, index = [], []
    for k, key in enumerate(match.lane_route):
        on = matched[match.route_index[matched] == k]
        index.append(len(out) if len(on) else -1)
        if len(on):
            out.append(Anchor(key, len(on), float(match.u[on[0]]), float(match.u[on[-1]]), float(along[on[0]]),
                              float(along[on[-1]])))
    return out, index


def replay_path(match, lines: LaneLines, codes: LaneCodes, speed: np.ndarray, min_step: float = 1.0,
                jitter_m: float = 5.0) -> PathChunk:
    """The recording drawn on the map: each matched fix's point on its lane's centre line, in recording
    order, joined along the lane where consecutive fixes share it. Points that repeat (standstill) or fall
    back by less than ``jitter_m`` (GNSS jitter) are dropped, so the path never reverses."""
    points: list[np.ndarray] = []
    speeds: list[float] = []
    lane_codes: list[int] = []
    last_key, last_u = None, 0.0

    def add(point, v, code):
        if points:
            step = point[:2] - points[-1][:2]
            distance = float(np.hypot(*step))
            if distance < min_step:
                return
            if len(points) >= 2:
                heading = points[-1][:2] - points[-2][:2]
                if float(np.dot(step, heading)) < 0 and distance < jitter_m:
                    return
        points.append(point)
        speeds.append(v)
        lane_codes.append(code)

    for i in np.flatnonzero(match.matched):
        key = match.lane(i)
        line = lines[key]
        u = float(np.clip(match.u[i], 0.0, line.length))
        code = codes.code(key)
        if key == last_key:  # follow the centre line between the two fixes, whichever way the ride went
            inner = line.along[(line.along > min(u, last_u)) & (line.along < max(u, last_u))]
            for a in (inner if u >= last_u else inner[::-1]):
                add(line.at(float(a))[0], speed[i], code)
        add(line.at(u)[0], speed[i], code)
        last_key, last_u = key, u
    return PathChunk(np.array(points), np.array(speeds), np.array(lane_codes, dtype=np.int64))


@dataclass(frozen=True, eq=False)
class RecordedRoute:
    path: Path
    lanes: tuple[LaneKey, ...]
    spans: tuple  # (Span, ...) of the lanes, trimmed to the first and last fix
    speeds: tuple  # per span: (along (m), speed (m/s)) arrays of the fixes on it, for interpolation
    matched_xy: tuple[np.ndarray, np.ndarray]
    floor_mean_m: float
    fix_count: int
    start_xy: tuple[float, float]
    lines: LaneLines
    codes: LaneCodes
    match_stats: dict
    replay: PathChunk | None = None  # mode "replay": the recording's own path on the lane centres

    @staticmethod
    def from_file(path, odr, graph: LaneGraph, lines: LaneLines, codes: LaneCodes,
                  mode: str = "replay") -> RecordedRoute:
        """``mode`` "replay": drive the matched lane centres in recording order, wherever the recording went
        (a replay, also against one-way lanes); "legal": the cheapest connected lane route through the
        matched lanes (``join_anchors``), as a car would drive it."""
        from tavf_mapkit.accuracy.matching import match_trace
        from tavf_mapkit.traces import read_trace

        path = Path(path)
        if odr.georeference is None:
            raise InputError("the map has no geoReference, so a GNSS trace cannot be placed on it")
        trace = read_trace(path)
        match = match_trace(odr, trace, graph)
        matched = np.flatnonzero(match.matched)
        if not len(matched) or not match.lane_route:
            raise InputError(f"no fix lies within {match.radius_m:.0f} m of a driving lane: the trace is outside "
                             "the map", file=str(path))
        anchors, anchor_index = anchors_of(match)
        lanes, placed_anchor = join_anchors(graph, anchors)
        placed = [placed_anchor[a] if a >= 0 else -1 for a in anchor_index]  # per lane_route entry
        spans = list(route_spans(lines, graph, lanes))
        first = int(matched[0])
        # the fix's lane position, if its lane is the route's first / last lane
        if match.lane(first) == lanes[0]:
            spans[0] = _with(spans[0], start=float(np.clip(match.u[first], 0.0, lines[lanes[0]].length)))
        reached = [i for i in matched if placed[match.route_index[i]] >= 0]
        if reached and match.lane(reached[-1]) == lanes[-1] and spans[-1].key == lanes[-1]:
            stop = float(np.clip(match.u[reached[-1]], 0.0, lines[lanes[-1]].length))
            if stop > spans[-1].start + 1.0:
                spans[-1] = _with(spans[-1], stop=stop)
        speeds = _span_speeds(spans, lanes, placed, match, trace, graph)
        start = lines[spans[0].key].at(spans[0].start)[0]
        replay = None
        if mode == "replay":
            recorded = trace.speed if trace.has("speed") else np.full(len(trace), np.nan)
            limits = np.array([graph.speed_limit(match.lane(i)) or DEFAULT_SPEED if match.matched[i] else np.nan
                               for i in range(len(trace))])
            speed = np.where(np.isfinite(recorded), np.maximum(recorded, MIN_SPEED), limits)
            replay = replay_path(match, lines, codes, np.minimum(speed, limits))
            if len(replay) < 2:
                raise InputError("the matched trace does not move (fewer than two distinct points)", file=str(path))
            start = replay.points[0]
        elif mode != "legal":
            raise InputError(f"unknown route mode {mode!r} (replay or legal)")
        return RecordedRoute(path, tuple(lanes), tuple(spans), tuple(speeds),
                             (match.x[matched], match.y[matched]), float(np.mean(match.floor_m[matched])),
                             len(trace), (float(start[0]), float(start[1])), lines, codes, match.stats(), replay)

    def chunks(self, piece: int = 512):
        if self.replay is not None:
            for lo in range(0, len(self.replay), piece):
                yield self.replay.slice(lo, lo + piece)
            return
        for span, (along, speed) in zip(self.spans, self.speeds):
            chunk = lane_chunk(self.lines, self.codes, span.key, span.start, span.stop)
            if not len(chunk):
                continue
            line = self.lines[span.key]
            point_along = _along_of(line, chunk.points)
            limit = chunk.speed_limit
            if len(along):
                recorded = np.maximum(np.interp(point_along, along, speed), MIN_SPEED)
                limit = np.minimum(limit, recorded)
            yield PathChunk(chunk.points, limit, chunk.lane_code)


def _with(span, **changes):
    from dataclasses import replace

    return replace(span, **changes)


def _along_of(line, points: np.ndarray) -> np.ndarray:
    """Distances along the lane of a chunk's points (a contiguous run of the line's own points)."""
    first = int(np.argmin(np.hypot(line.points[:, 0] - points[0, 0], line.points[:, 1] - points[0, 1])))
    return line.along[first:first + len(points)]


def _span_speeds(spans, lanes, placed, match, trace, graph):
    """Per span, the recorded speeds of the fixes matched to its lane (sorted by position along the lane);
    spans without fixes take the speed of the nearest fixes in route order."""
    route_fix_speed: dict[int, list[tuple[float, float]]] = {}
    have_speed = trace.has("speed")
    for i in np.flatnonzero(match.matched):
        position = placed[match.route_index[i]]
        if position < 0 or not have_speed or not np.isfinite(trace.speed[i]):
            continue
        route_fix_speed.setdefault(position, []).append((float(match.u[i]), float(trace.speed[i])))
    known = sorted(route_fix_speed)
    out = []
    for span in spans:
        pairs = route_fix_speed.get(span.index)
        if not pairs and known:
            nearest = min(known, key=lambda k: abs(k - span.index))
            pairs = [(0.0, float(np.median([v for _, v in route_fix_speed[nearest]])))]
        if not pairs:
            out.append((np.zeros(0), np.zeros(0)))
            continue
        pairs.sort()
        out.append((np.array([a for a, _ in pairs]), np.array([v for _, v in pairs])))
    return out
