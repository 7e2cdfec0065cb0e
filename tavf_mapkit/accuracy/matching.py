"""HMM map matching of GNSS fixes to lanes (Newson & Krumm 2009, with headings), on the lane graph.

Hidden states are candidate lanes near each fix. Emission: Gaussian in the distance to the lane centre line
(sigma ~ the GNSS noise) times a von Mises factor in the difference between the fix's heading and the lane's
driving direction (only where the fix moves, a stationary phone's heading is stale). Transition: exponential
in | route distance through the lane graph - straight distance between the fixes | (scale beta), so routes
that detour, drive against the lane direction or jump between unconnected lanes lose. Viterbi picks the best
sequence; where no transition is possible the chain restarts (a break). The lane route joins the chosen lanes
with shortest paths, so it is a drivable sequence of lanes.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np

from tavf_mapkit.errors import InputError
from tavf_mapkit.lanegraph import LaneGraph, LaneIndex, LaneKey, NoRouteError


@dataclass(frozen=True, eq=False)
class MatchResult:
    """Per fix (arrays of equal length) and the lane route. Unmatched fixes: -1 / "" / NaN."""

    x: np.ndarray
    y: np.ndarray
    matched: np.ndarray
    road_index: np.ndarray
    road_id: np.ndarray
    section_index: np.ndarray
    lane_id: np.ndarray
    s: np.ndarray
    t: np.ndarray
    u: np.ndarray             # metres along the matched lane in driving direction
    distance_m: np.ndarray    # to the matched lane's centre line
    floor_m: np.ndarray       # to the nearest lane centre line (any lane of the graph), every fix
    lane_route: tuple[LaneKey, ...]
    route_index: np.ndarray   # index into lane_route of each matched fix
    route_breaks: tuple[int, ...]  # i where lane_route[i - 1] -> lane_route[i] is not connected
    breaks: tuple[int, ...]   # fixes where the chain restarts (the first fix, or after fixes out of reach)
    jumps: tuple[int, ...]    # fixes reached from the previous one by no legal route (priced, not forbidden)
    sigma_m: float
    radius_m: float
    parameters: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.x)

    def route_legs(self) -> list[tuple[LaneKey, ...]]:
        """The lane route split at its breaks into connected, drivable pieces."""
        cuts = [0, *self.route_breaks, len(self.lane_route)]
        return [self.lane_route[a:b] for a, b in itertools.pairwise(cuts) if b > a]

    def lane(self, i: int) -> LaneKey | None:
        if not self.matched[i]:
            return None
        return LaneKey(int(self.road_index[i]), int(self.section_index[i]), int(self.lane_id[i]))

    def stats(self) -> dict:
        """The JSON contract of ``mapkit match-trace``: distances over matched fixes, in metres."""
        d = self.distance_m[self.matched]
        floor = self.floor_m[self.matched]

        def figure(values, function):
            return round(float(function(values)), 3) if len(values) else None

        return {
            "fixes": len(self.x),
            "matched": int(self.matched.sum()),
            "matched_fraction": round(float(self.matched.mean()), 4) if len(self.x) else 0.0,
            "mean_m": figure(d, np.mean),
            "median_m": figure(d, np.median),
            "p95_m": figure(d, lambda v: np.percentile(v, 95)),
            "max_m": figure(d, np.max),
            "floor_mean_m": figure(floor, np.mean),
            "floor_median_m": figure(floor, np.median),
            "route_lanes": len(self.lane_route),
            "route_breaks": len(self.route_breaks),
            "breaks": len(self.breaks),
            "jumps": len(self.jumps),
            "sigma_m": round(self.sigma_m, 3),
            "radius_m": round(self.radius_m, 3),
        }


def _fix_inputs(odr, trace):
    """(x, y, heading or NaN, speed or NaN, accuracy or NaN) in the map's local frame."""
    from tavf_mapkit.traces import Trace

    if isinstance(trace, Trace):
        if odr.georeference is None:
            raise InputError("the map has no geoReference, so WGS84 fixes cannot be placed on it",
                             file=odr.source)
        x, y = trace.local_xy(odr.georeference)
        return x, y, trace.local_heading(odr.georeference), np.asarray(trace.speed), np.asarray(trace.accuracy)
    columns = [np.atleast_1d(np.asarray(c, dtype=float)) for c in trace]
    x, y = columns[0], columns[1]
    heading = columns[2] if len(columns) > 2 else np.full(len(x), np.nan)
    return x, y, heading, np.full(len(x), np.nan), np.full(len(x), np.nan)


def _usable_heading(x, y, heading, speed, min_speed: float, min_motion: float) -> np.ndarray:
    """The fix heading where the fix moves; else the direction of motion over its neighbours; else NaN."""
    heading = np.where(np.isfinite(speed) & (speed < min_speed), np.nan, heading)
    if len(x) >= 2:
        before = np.r_[0, np.arange(len(x) - 1)]
        after = np.r_[np.arange(1, len(x)), len(x) - 1]
        dx, dy = x[after] - x[before], y[after] - y[before]
        motion = np.where(np.hypot(dx, dy) >= min_motion, np.arctan2(dy, dx), np.nan)
        heading = np.where(np.isfinite(heading), heading, motion)
    return heading


class _Routes:
    """Route costs between lanes through the graph, from bounded Dijkstra runs cached per source lane."""

    def __init__(self, graph: LaneGraph, keys: list[LaneKey], reach_m: float):
        self.graph, self.keys, self.reach = graph, keys, reach_m
        self.position = {k: i for i, k in enumerate(keys)}
        self.cache: dict[int, dict[int, float]] = {}

    def costs_from(self, node: int) -> dict[int, float]:
        costs = self.cache.get(node)
        if costs is None:
            key = self.keys[node]
            lengths = self.graph.distances_from(key, cutoff=self.graph.length(key) + self.reach)
            costs = {self.position[k]: v for k, v in lengths.items()}
            self.cache[node] = costs
        return costs


def match_trace(odr, trace, graph: LaneGraph | None = None, *, sigma_m: float | None = None,
                radius_m: float | None = None, candidates: int = 8, beta_m: float = 10.0,
                heading_kappa: float = 2.0, min_speed: float = 1.0, backtrack_m: float | None = None,
                jump_penalty: float = 20.0, detour_factor: float = 3.0, detour_min_m: float = 100.0,
                lane_types=("driving",), index: LaneIndex | None = None) -> MatchResult:
    """Match a Trace (WGS84, placed through the map's georeference) or local ``(x, y[, heading])`` arrays.

    sigma_m: GNSS noise (default: the trace's median reported accuracy, clipped to 1..15 m, else 5 m).
    radius_m: fixes with no lane centre line this close stay unmatched (default max(20, 4 sigma)).
    beta_m: scale of the transition penalty. heading_kappa: weight of heading agreement (0 ignores it).
    backtrack_m: how far a fix may fall back along the same lane (GNSS jitter; default 2 sigma).
    """
    graph = graph or LaneGraph.from_opendrive(odr, lane_types=lane_types)
    if len(graph) == 0:
        raise InputError(f"the map has no lanes of type {', '.join(lane_types)} to match to", file=odr.source)
    x, y, heading, speed, accuracy = _fix_inputs(odr, trace)
    n = len(x)
    if n == 0:
        raise InputError("the trace has no fixes (empty trace)")
    if sigma_m is None:
        finite = accuracy[np.isfinite(accuracy) & (accuracy > 0)]
        sigma_m = float(np.clip(np.median(finite), 1.0, 15.0)) if len(finite) else 5.0
    radius_m = float(radius_m if radius_m is not None else max(20.0, 4.0 * sigma_m))
    backtrack_m = 2.0 * sigma_m if backtrack_m is None else backtrack_m
    heading = _usable_heading(x, y, heading, speed, min_speed, min_motion=max(2.0, 0.5 * sigma_m))

    index = index or LaneIndex(graph)
    floor = index.nearest(x, y).distance
    found = index.candidates(x, y, radius_m, per_point=candidates)
    # the nearest lane is a candidate too when in reach; keep the floor consistent with it
    nearest_candidate = np.full(n, np.inf)
    np.minimum.at(nearest_candidate, found.point, found.distance)
    floor = np.minimum(floor, nearest_candidate)
    starts = np.searchsorted(found.point, np.arange(n + 1), side="left")
    emission = -0.5 * (found.distance / sigma_m) ** 2
    fix_heading = heading[found.point]
    agree = np.cos(fix_heading - found.heading)
    emission = emission + np.where(np.isfinite(agree), heading_kappa * (agree - 1.0), 0.0)

    step = np.hypot(np.diff(x), np.diff(y)) if n > 1 else np.zeros(0)
    reach = max(200.0, 4.0 * float(step.max(initial=0.0)) + 4.0 * radius_m)
    routes = _Routes(graph, index.keys, reach)

    # Viterbi; score arrays are per candidate of the current fix
    back = np.full(len(found.point), -1, dtype=np.int64)
    score = np.full(len(found.point), -np.inf)
    breaks: list[int] = []
    previous = None  # fix index of the last fix with candidates
    for i in range(n):
        lo, hi = starts[i], starts[i + 1]
        if lo == hi:
            continue
        if previous is None:
            score[lo:hi] = emission[lo:hi]
            breaks.append(i)
            previous = i
            continue
        plo, phi = starts[previous], starts[previous + 1]
        straight = math.hypot(x[i] - x[previous], y[i] - y[previous])
        route = np.full((phi - plo, hi - lo), np.inf)
        for a in range(plo, phi):
            node_a = found.node[a]
            costs = routes.costs_from(int(node_a))
            for b in range(lo, hi):
                node_b = found.node[b]
                if node_b == node_a:
                    du = found.u[b] - found.u[a]
                    if du >= -backtrack_m:
                        route[a - plo, b - lo] = abs(du)
                    # a lane left and re-entered (a loop) is not worth following
                else:
                    cost = costs.get(int(node_b))
                    if cost is not None:
                        route[a - plo, b - lo] = max(cost - found.u[a] + found.u[b], 0.0)
        # no legal route (a turn cars may not make, a path the map lacks): allowed, at a fixed price
        transition = np.maximum(-np.abs(route - straight) / beta_m, -jump_penalty)
        total = score[plo:phi, None] + transition
        best = np.argmax(total, axis=0)
        best_total = total[best, np.arange(hi - lo)]
        if not np.any(np.isfinite(best_total)):
            score[lo:hi] = emission[lo:hi]
            breaks.append(i)
        else:
            score[lo:hi] = best_total + emission[lo:hi]
            back[lo:hi] = np.where(np.isfinite(best_total), plo + best, -1)
        previous = i

    # backtrack from the end of every chain
    chosen = np.full(n, -1, dtype=np.int64)
    i = n - 1
    while i >= 0:
        lo, hi = starts[i], starts[i + 1]
        if lo == hi or chosen[i] >= 0:
            i -= 1
            continue
        current = lo + int(np.argmax(score[lo:hi]))
        while current >= 0:
            fix = int(found.point[current])
            if chosen[fix] >= 0:
                break
            chosen[fix] = current
            current = int(back[current])
        i -= 1

    jumps = []
    previous = None
    for i in np.flatnonzero(chosen >= 0):
        if previous is not None and int(i) not in breaks:
            a, b = chosen[previous], chosen[i]
            node_a, node_b = int(found.node[a]), int(found.node[b])
            legal = (found.u[b] - found.u[a] >= -backtrack_m) if node_a == node_b \
                else node_b in routes.costs_from(node_a)
            if not legal:
                jumps.append(int(i))
        previous = i
    parameters = {"beta_m": beta_m, "heading_kappa": heading_kappa, "candidates": candidates,
                  "jump_penalty": jump_penalty, "detour_factor": detour_factor, "detour_min_m": detour_min_m,
                  "lane_types": list(lane_types)}
    return _result(odr, graph, index, found, chosen, x, y, floor, breaks, jumps, sigma_m, radius_m, parameters)


def _result(odr, graph, index, found, chosen, x, y, floor, breaks, jumps, sigma_m, radius_m,
            parameters) -> MatchResult:
    n = len(x)
    matched = chosen >= 0
    pick = chosen[matched]
    nodes = found.node[pick]
    keys = [index.keys[k] for k in nodes]
    road_index = np.full(n, -1, dtype=np.int64)
    section_index = np.full(n, -1, dtype=np.int64)
    lane_id = np.zeros(n, dtype=np.int64)
    road_id = np.full(n, "", dtype=object)
    s, t, u, distance = (np.full(n, np.nan) for _ in range(4))
    if len(pick):
        road_index[matched] = [k.road_index for k in keys]
        section_index[matched] = [k.section_index for k in keys]
        lane_id[matched] = [k.lane_id for k in keys]
        road_id[matched] = [odr.roads[k.road_index].id for k in keys]
        s[matched] = found.s[pick]
        u[matched] = found.u[pick]
        distance[matched] = found.distance[pick]
        px, py, _, ref_heading, *_ = odr.arrays.reference(road_index[matched], s[matched])
        t[matched] = (-(x[matched] - px) * np.sin(ref_heading) + (y[matched] - py) * np.cos(ref_heading))
    lane_route, route_index, route_breaks = _lane_route(
        graph, keys, u[matched], x[matched], y[matched], parameters["detour_factor"], parameters["detour_min_m"])
    full_route_index = np.full(n, -1, dtype=np.int64)
    full_route_index[matched] = route_index
    return MatchResult(x, y, matched, road_index, road_id, section_index, lane_id, s, t, u, distance, floor,
                       tuple(lane_route), full_route_index, tuple(route_breaks), tuple(breaks), tuple(jumps),
                       float(sigma_m),
                       float(radius_m), parameters)


def _lane_route(graph: LaneGraph, keys: list[LaneKey], u: np.ndarray, x: np.ndarray, y: np.ndarray,
                detour_factor: float, detour_min_m: float) -> tuple[list[LaneKey], list[int], list[int]]:
    """Consecutive distinct lanes of the matched fixes, joined by shortest paths where they do not touch.

    A path is used only if driving it is at most ``detour_factor`` times the straight distance between the
    two fixes (and at least ``detour_min_m`` is always allowed); otherwise the fixes went where no car goes
    and the route is left disconnected there (``route_breaks``: indices i where lane_route[i-1] -> [i] is
    not an edge of the graph).
    """
    route: list[LaneKey] = []
    positions: list[int] = []
    route_breaks: list[int] = []
    for i, key in enumerate(keys):
        if not route:
            route.append(key)
        elif key != route[-1]:
            previous = route[-1]
            path = None
            if graph.has_edge(previous, key):
                path = [previous, key]
            else:
                try:
                    path = graph.shortest_path(previous, key)
                except NoRouteError:
                    pass
            if path is not None and len(path) > 2:
                driven = graph.path_cost(path) - u[i - 1] + u[i]
                allowed = max(detour_min_m, detour_factor * math.hypot(x[i] - x[i - 1], y[i] - y[i - 1]))
                if driven > allowed:
                    path = None
            if path is None:
                route_breaks.append(len(route))
                route.append(key)
            else:
                route.extend(path[1:])
        positions.append(len(route) - 1)
    return route, positions, route_breaks
