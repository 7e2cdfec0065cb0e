"""Which lanes, and which steps from one lane to the next, a car can drive in lane, measured as a car meets
them.

Two things a car cannot follow:

- a U-turn: the car's heading turns by more than 135 degrees, inside a lane or from the lane before to
  the lane after. netconvert draws its turnarounds as a hairpin that starts and ends at an angle to the
  roads it joins (the lane alone turns some 125 degrees), sometimes as a lane of a few centimetres.
- a bend tighter than the car turns. A car turns no tighter than ``min_turn_radius`` R (wheelbase over the
  tangent of its largest steering angle: 5.6 m for the Model S at the controllers' steering limit). On a
  bend of angle D and radius r < R it cuts inside by (R - r) (1 / cos(D / 2) - 1), the distance between
  the bend's and the car's arcs at the apex. ``corner_cut`` measures this at every point of a centre line
  over windows of 1 to 16 m of arc (D: the heading change over the window, r: the window over D, as in
  ``wheelbase_curvature``): a polyline kink of 20 degrees costs 9 cm whatever its "radius", a right-angled
  corner 2 m, a junction turn of 5 m radius nothing. Lanes and steps that cut more than ``MAX_CUT`` are
  not driven.

Measuring is the costly part of a map's start (every lane and every step of a region), and most lanes
barely turn: a line whose headings turn by T in all can be cut by at most R (1 / cos(T / 2) - 1) (the
window's heading change never exceeds T, the car's radius never exceeds R), so ``worst_cuts`` measures only
the lines whose bound exceeds ``MAX_CUT`` and the decision for every other line is the same.

A step from lane a to lane b (a "transition") may pass sub-metre lanes, which add no points to a path
(``DEGENERATE_LANE``), and a gap the path buffer bridges with a diagonal (``join_cut``); it is measured on
the polyline the path will have: the end of a without what the diagonal replaces, then the start of b.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from tavf_mapkit.lanegraph import LaneGraph, LaneKey
from tavf_mapkit.mesh.exact import run_cumsum
from tavf_mapkit.mesh.swept_path import wheelbase_curvatures
from twin.control.pid import CARLA_LIMITS, ActuatorLimits
from twin.map import lanelines
from twin.map.lanelines import ENDS_HEAD, ENDS_TAIL, LaneEnds, LaneLines
from twin.planning import steps
from twin.planning.buffer import JOIN_GAP, join_cut, join_gap, straight_cut
from twin.planning.chunks import DEGENERATE_LANE
from twin.vehicle.params import MODEL_S, VehicleParams

U_TURN = np.radians(135.0)
# m a car at its tightest turn may cut a bend. Measured drives deviate about twice as far as this ideal arc
# (the controller turns in late and swings out): geometric cuts of 0.6-0.8 m put the car's wheels on the
# outer curb of 125-degree junction turns in Paris, 1.4 m ones on Perth's; 0.5 m keeps it inside its lane
MAX_CUT = 0.5
WINDOWS = (1.0, 2.0, 4.0, 8.0, 16.0)  # m of arc over which bends are measured
REACH = 8.0  # m of each lane around a transition that the measure looks at
# a lane's ends kept for measuring steps (``LaneLines.ends``) cover REACH
assert ENDS_HEAD >= REACH and ENDS_TAIL >= REACH
CHAIN = 4  # sub-metre lanes (and one U-turn lane) a transition may pass


def min_turn_radius(params: VehicleParams = MODEL_S, limits: ActuatorLimits = CARLA_LIMITS) -> float:
    """The tightest radius (m, rear axle) the twin's car turns at the controllers' steering limit."""
    return params.wheelbase / math.tan(params.max_steer * limits.max_steering)


def corner_cut(lane: np.ndarray, points: np.ndarray, radius: float) -> np.ndarray:
    """Per point of polylines (runs of equal ``lane``): how far (m) a car turning no tighter than ``radius``
    cuts inside the bend there, the largest over ``WINDOWS`` (near a run's ends the window is cut short)."""
    # points closer than a path buffer's join tolerance (lane ends that nearly meet) give a step whose heading
    # is noise, not a turn: they take their predecessor's value
    distinct = _distinct(lane, points)
    if not np.all(distinct):
        return corner_cut(lane[distinct], points[distinct], radius)[np.cumsum(distinct) - 1]
    step = np.r_[np.inf, np.hypot(*np.diff(points, axis=0).T)]
    first = np.r_[True, lane[1:] != lane[:-1]]
    step[first] = 0.0
    run = np.cumsum(first) - 1
    arc = run_cumsum(step, run)  # metres from the run's start, each run's own sums (whatever runs go with it)
    length = np.zeros(run[-1] + 1 if len(run) else 0)
    np.maximum.at(length, run, arc)
    cut = np.zeros(len(points))
    for window, curvature in zip(WINDOWS, wheelbase_curvatures(lane, points, WINDOWS)):
        span = np.minimum(arc + 0.5 * window, length[run]) - np.maximum(arc - 0.5 * window, 0.0)
        turn = np.minimum(curvature * span, 0.9 * np.pi)  # the heading change over the window
        own_radius = 1.0 / np.maximum(curvature, 1e-9)
        cut = np.maximum(cut, np.maximum(radius - own_radius, 0.0) * (1.0 / np.cos(0.5 * turn) - 1.0))
    return cut


def _distinct(lane: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Points farther than ``JOIN_GAP`` from the point before them, and the first point of each run of equal
    ``lane``: what ``corner_cut`` measures (in a first pass; it thins what remains again)."""
    if not len(points):
        return np.zeros(0, dtype=bool)
    return np.r_[True, (np.hypot(*np.diff(points, axis=0).T) > JOIN_GAP) | (lane[1:] != lane[:-1])]


def total_turning(lane: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Per run of equal ``lane`` (runs numbered 0, 1, ... in order): the sum of the absolute heading changes
    between its consecutive segments, radians. Dropping a vertex never adds turning, so this bounds the
    turning of the thinned lines ``corner_cut`` measures too."""
    run = np.cumsum(np.r_[True, lane[1:] != lane[:-1]]) - 1
    d = np.diff(points, axis=0)
    heading = np.arctan2(d[:, 1], d[:, 0])
    inside = (run[1:-1] == run[:-2]) & (run[2:] == run[1:-1])  # consecutive segments of one run
    turn = np.abs(_wrap(np.diff(heading)))
    return np.bincount(run[1:-1][inside], weights=turn[inside], minlength=run[-1] + 1 if len(run) else 0)


def worst_cuts(lane: np.ndarray, points: np.ndarray, radius: float, limit: float,
               turning: np.ndarray | None = None) -> np.ndarray:
    """Per run of equal ``lane`` (runs numbered 0, 1, ... in order): the largest ``corner_cut``; for a run that
    turns too little to cut by more than ``limit`` (see the module docstring), that bound instead, at most
    ``limit``: only the comparison with ``limit`` is exact for those. ``turning``: the runs' ``total_turning``
    when the caller has it."""
    run = np.cumsum(np.r_[True, lane[1:] != lane[:-1]]) - 1
    # the turning of the line corner_cut measures, without the points it drops (dropping more never adds
    # turning): where two lanes meet, a's last point and b's first one coincide and their "segment" has any
    # heading, a half circle of turning in the raw line (every step of a region was measured for it)
    distinct = _distinct(lane, points)
    turning = total_turning(lane, points) if turning is None else np.array(turning, dtype=float)
    if not np.all(distinct):
        thinned = np.unique(run[~distinct])
        kept = np.isin(run, thinned) & distinct
        turning[thinned] = total_turning(run[kept], points[kept])
    # corner_cut caps a window's heading change at 0.9 pi; a thousandth below the limit for rounding
    turning = np.minimum(turning, 0.9 * np.pi)
    worst = radius * (1.0 / np.cos(0.5 * turning) - 1.0)
    measure = worst > 0.999 * limit
    worst[measure] = 0.0
    picked = measure[run]
    if np.any(picked):
        np.maximum.at(worst, run[picked], corner_cut(run[picked], points[picked], radius))
    return worst


def _wrap(angle):
    return (angle + np.pi) % (2 * np.pi) - np.pi


def _headings(lines: LaneLines, key: LaneKey) -> tuple[float, float]:
    """Driving heading of the lane's first and last segment."""
    ends = lines.ends(key)
    return _end_headings(ends.head[:2], ends.tail[-2:])


def _end_headings(head: np.ndarray, tail: np.ndarray) -> tuple[float, float]:
    """Heading of the segment from head[0] to head[1] and of the one from tail[-2] to tail[-1] (plan view)."""
    first, last = head[1] - head[0], tail[-1] - tail[-2]
    return float(np.arctan2(first[1], first[0])), float(np.arctan2(last[1], last[0]))


def undrivable_lanes(graph: LaneGraph, lines: LaneLines, radius: float | None = None,
                     max_cut: float = MAX_CUT) -> dict[LaneKey, str]:
    """Lanes of at least ``DEGENERATE_LANE`` a car cannot drive in lane, with the reason ("u-turn" or
    "cuts a bend by X m"). Every lane's line is measured once, batch by batch (``LaneLines.scan``): a
    region's lines are not kept, only their ends, which is all the steps between lanes are measured on."""
    radius = min_turn_radius() if radius is None else radius
    measured, cut, turn, first_heading, last_heading = [], [], [], [], []
    # every lane is measured on its own, so batches give the same numbers
    for batch in lines.scan(sorted(graph.keys)):
        counts = batch.counts
        chosen = np.flatnonzero((batch.length >= DEGENERATE_LANE) & (counts >= 2))
        if not len(chosen):
            continue
        measured.extend(batch.keys[i] for i in chosen.tolist())
        counts = counts[chosen]
        lane = np.repeat(np.arange(len(chosen)), counts)
        first = np.cumsum(counts) - counts
        points = batch.points[np.repeat(batch.at[chosen] - first, counts) + np.arange(len(lane)), :2]
        # each lane's first and last segment (``_end_headings``)
        start, stop = points[first + 1] - points[first], points[first + counts - 1] - points[first + counts - 2]
        first_heading.append(np.arctan2(start[:, 1], start[:, 0]))
        last_heading.append(np.arctan2(stop[:, 1], stop[:, 0]))
        cut.append(worst_cuts(lane, points, radius, max_cut, batch.turning[chosen]))
        turn.append(batch.turn[chosen])
    if not measured:
        return {}
    cut, turn = np.concatenate(cut), np.concatenate(turn)
    heading = dict(zip(measured, zip(np.concatenate(first_heading).tolist(), np.concatenate(last_heading).tolist())))
    found = {}
    for k, worst, own in zip(measured, cut, turn):
        u_turn = abs(own) > U_TURN
        if not u_turn and graph.odr.roads[k.road_index].in_junction:
            before = [heading[p][1] for p in graph.predecessors(k) if p in heading]
            after = [heading[q][0] for q in graph.successors(k) if q in heading]
            u_turn = any(abs(_wrap(b - a)) > U_TURN for a in before for b in after)
        if u_turn:
            found[k] = "u-turn"
        elif worst > max_cut:
            found[k] = f"cuts a bend by {worst:.1f} m"
    return found


@dataclass
class Transitions:
    """Steps between drivable lanes of at least ``DEGENERATE_LANE``: ``follow`` a car drives; ``u_turn``
    only by turning around (through a U-turn lane or a U-turn step); ``dropped`` with their reason;
    ``blocked``: lanes the map leads on from, but only into a bend the car cannot drive (a dropped step or an
    undrivable lane ahead), so where such a lane has no other way on, the dead end is ours, not the map's."""

    follow: dict[LaneKey, list[LaneKey]] = field(default_factory=dict)
    u_turn: dict[LaneKey, list[LaneKey]] = field(default_factory=dict)
    dropped: dict[tuple[LaneKey, LaneKey], str] = field(default_factory=dict)
    blocked: set[LaneKey] = field(default_factory=set)


def lane_transitions(graph: LaneGraph, lines: LaneLines, undrivable: dict[LaneKey, str],
                     radius: float | None = None, max_cut: float = MAX_CUT) -> Transitions:
    radius = min_turn_radius() if radius is None else radius

    def usable(k):
        return k not in undrivable and lines.length(k) >= DEGENERATE_LANE

    result = Transitions()
    keys = graph.keys
    usable_node = np.fromiter((usable(k) for k in keys), dtype=bool, count=len(keys))
    for a in sorted(keys[i] for i in np.flatnonzero(usable_node).tolist()):
        result.follow[a], result.u_turn[a] = [], []
    # a lane whose successors are all usable steps straight into them (nearly every lane of a region): its
    # candidates at once; the walk below only for lanes with a sub-metre, U-turn or undrivable lane ahead
    source, target = graph.follow_edges()
    walk = np.zeros(len(keys), dtype=bool)
    walk[source[~usable_node[target]]] = True
    direct = usable_node[source] & ~walk[source]
    candidates: list[tuple[LaneKey, LaneKey]] = [(keys[i], keys[j]) for i, j in
                                                 zip(source[direct].tolist(), target[direct].tolist())]
    for a in sorted(keys[i] for i in np.flatnonzero(usable_node & walk).tolist()):
        frontier, seen, turned_to = [(a, False)], set(), set()
        for _ in range(CHAIN + 1):
            ahead = []
            for x, turned in frontier:
                for b in graph.successors(x):
                    if usable(b):
                        if turned:
                            turned_to.add(b)
                        else:
                            candidates.append((a, b))
                    elif (b, turned) not in seen:
                        u_turn_lane = undrivable.get(b) == "u-turn"
                        if u_turn_lane or (b not in undrivable and lines.length(b) < DEGENERATE_LANE):
                            seen.add((b, turned))
                            ahead.append((b, turned or u_turn_lane))
                        elif b in undrivable and not turned:
                            result.blocked.add(a)
            frontier = ahead
        result.u_turn[a] = sorted(turned_to)
    candidates = sorted(set(candidates))
    if not candidates:
        return result
    # the polyline of every step, measured many at once: steps whose lanes meet straight from the lanes' kept
    # ends, all at once (``steps``); the others one by one. In batches of about BATCH_POINTS points (a region
    # has millions), each step on its own, so batches give the same numbers
    ends = lines.ends_arrays()
    row = ends.index
    table = np.array([a in row and b in row for a, b in candidates])
    a_row = np.array([row[a] if t else 0 for (a, _), t in zip(candidates, table)], dtype=np.int64)
    b_row = np.array([row[b] if t else 0 for (_, b), t in zip(candidates, table)], dtype=np.int64)
    on_table = np.flatnonzero(table)
    cut = np.zeros(len(candidates))
    alone = np.ones(len(candidates), dtype=bool)
    # steps a part at a time (a step is some 20 points: a part about BATCH_POINTS), so that a region's steps
    # are never gathered all at once
    part_steps = max(lanelines.BATCH_POINTS // 32, 1)
    for low in range(0, len(on_table), part_steps):
        part = on_table[low:low + part_steps]
        joined, owner, points = steps.joined_steps(ends, a_row[part], b_row[part])
        for start, stop in _batches(owner):
            measured = worst_cuts(owner[start:stop], points[start:stop], radius, max_cut)
            cut[part[np.unique(owner[start:stop])]] = measured
        alone[part[joined]] = False
    alone = np.flatnonzero(alone).tolist()
    polylines, count = [], 0
    for n, k in enumerate(alone):
        polylines.append(_step_polyline(lines, *candidates[k]))
        count += len(polylines[-1])
        if count >= lanelines.BATCH_POINTS or n == len(alone) - 1:
            lane = np.repeat(np.arange(len(polylines)), [len(p) for p in polylines])
            cut[alone[n + 1 - len(polylines):n + 1]] = worst_cuts(lane, np.concatenate(polylines), radius, max_cut)
            polylines, count = [], 0
    first_heading, last_heading = steps.end_headings(ends)
    for (a, b), worst, t, i, j in zip(candidates, cut.tolist(), table.tolist(), a_row.tolist(), b_row.tolist()):
        turn = (float(first_heading[j]) - float(last_heading[i]) if t
                else _headings(lines, b)[0] - _headings(lines, a)[1])
        if abs(_wrap(turn)) > U_TURN:
            result.dropped[a, b] = "u-turn"
            result.u_turn[a].append(b)
        elif worst > max_cut:
            result.dropped[a, b] = f"cuts a bend by {worst:.1f} m"
            result.blocked.add(a)
        else:
            result.follow[a].append(b)
    for a in result.u_turn:
        result.u_turn[a] = sorted(set(result.u_turn[a]))
    return result


def _batches(owner: np.ndarray):
    """(start, stop) of runs of about ``BATCH_POINTS`` points that end where a step (equal ``owner``) ends."""
    start = 0
    while start < len(owner):
        stop = min(start + lanelines.BATCH_POINTS, len(owner))
        stop = int(np.searchsorted(owner, owner[stop - 1], side="right"))
        yield start, stop
        start = stop


def _step_polyline(lines: LaneLines, a: LaneKey, b: LaneKey) -> np.ndarray:
    """The end of lane a and the start of lane b as the path buffer joins them (plan view): the blend's
    diagonal (``join_cut``) replaces only the straight end of a (``straight_cut``), as in the buffer. Read
    from the lanes' ends (``LaneEnds``); the whole line of a when the blend reaches back beyond them."""
    la, lb = lines.ends(a), lines.ends(b)
    end = la.tail[-1]
    before = la.tail[-2] if len(la.tail) > 1 else end
    cut = 0.0
    if float(np.hypot(*(lb.head[0] - end))) > JOIN_GAP:
        cut = join_cut(*join_gap(end, math.atan2(end[1] - before[1], end[0] - before[0]), lb.head[0]))
        if not la.tail_from(la.length - cut - REACH):
            la = LaneEnds.of(lines.line(a))
        cut = straight_cut(la.tail, la.tail_along, cut)
    end = la.length - cut
    tail = la.tail[(la.tail_along >= end - REACH) & (la.tail_along <= end + 1e-9)]
    if not len(tail):
        tail = la.head[:1]
    return np.concatenate([tail, lb.head[lb.head_along <= REACH]])
