"""Random routes that always make progress: a walk through the lane graph that never stalls and never loops.

Lanes and steps between them: those a car can drive in lane (``twin.planning.drivable``: no U-turns, no
bend the car would cut by more than half a metre, measured on lanes and on the joins between them);
sub-metre lanes, which add no points to a path, are stepped over. Lane changes are part of the walk,
because on real networks turn lanes often make the follow-only graph fall apart.

Where the walk goes, in order of preference:

1. ``loop``: the largest strongly connected component of follow and lane-change edges that has a cycle
   covering distance (a follow edge; every lane of the walk is at least ``DEGENERATE_LANE`` long). A cycle
   of lane changes alone never counts: changing lanes does not move a car along the road, and a walk that
   only changes lanes would never get anywhere.
2. ``turnaround``: where closed loops are missing or cover less than half of what turnarounds open up
   (rural trees, a single two-way street, streets the extract cut off): at a dead end (a lane without a
   follow edge and no lane change towards one) the walk turns around onto the nearest lane of the opposite
   direction at the same end of the road: where netconvert's turnaround leads, or a lane of the other side
   of the same lane section. The largest component of that graph is used.
3. ``restart``: neither exists (one-way dead ends only): the walk drives until a dead end, then restarts
   on a new random lane.

Dead ends of our own making are left out first: a lane the map leads on from, but only into a bend the car
cannot drive, with no lane change towards a lane that drives on and nowhere to turn around, is dropped, and so
is a lane that leads only into dropped ones (the walk would stop in the middle of a junction and restart
there). Restarts and turnarounds happen where the map ends.

Turnarounds and restarts appear in the walk as ``RouteBreak`` items; the twin performs them (docs/twin.md).
Inside the chosen lanes every lane has a way on, lane changes are only made towards a lane that can drive
on (or once, voluntarily, into a lane that can), so a run of lane changes is bounded by the lanes of one
section and every step of the walk is bounded in time.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterator

import numpy as np

from tavf_mapkit.errors import InputError
from tavf_mapkit.lanegraph import LaneGraph, LaneKey
from tavf_mapkit.lanegraph.edges import strong_components
from tavf_mapkit.memory import collector_paused
from twin.map.lanelines import LaneLines
from twin.planning.chunks import DEGENERATE_LANE, RESTART, TURNAROUND, LaneCodes, PathChunk, RouteBreak, \
    expand_route
from twin.planning.drivable import MAX_CUT, lane_transitions, undrivable_lanes

MIN_LANE_CHANGE_LENGTH = 30.0  # m: shorter lanes change lanes only when they must
TURNAROUND_SHARE = 0.5  # loops must cover this share of what turnarounds reach, else turnarounds are used


class RandomRoutes:
    def __init__(self, graph: LaneGraph, lines: LaneLines, max_cut: float = MAX_CUT,
                 lane_change_probability: float = 0.2):
        self.graph = graph
        self.lines = lines
        self.lane_change_probability = lane_change_probability
        # route selection makes hundreds of thousands of small lists, sets and dicts and next to no cycles: each
        # of the collector's passes would walk them all again (region-60: 1.7 of 4.7 s CPU after the lines)
        with collector_paused():
            self._select(graph, lines, max_cut)

    def _select(self, graph: LaneGraph, lines: LaneLines, max_cut: float) -> None:
        self.undrivable = undrivable_lanes(graph, lines, max_cut=max_cut)
        self.transitions = lane_transitions(graph, lines, self.undrivable, max_cut=max_cut)
        follow = self.transitions.follow
        keep = set(follow)  # drivable lanes of DEGENERATE_LANE or more
        lateral = {k: [b for b in graph.lane_changes(k) if b in keep] for k in keep}
        # lanes by section, of every lane kept so far: its users ask only for lanes still kept, so one table
        # serves while lanes are dropped (sorting a region's lanes again for each round cost seconds)
        by_section = self._by_section(keep)
        keep = self._without_blocked_ends(keep, follow, lateral, by_section)
        follow = {k: [b for b in follow[k] if b in keep] for k in keep}
        lateral = {k: [b for b in lateral[k] if b in keep] for k in keep}
        turnaround = self._turnarounds(keep, follow, by_section)
        loop = self._largest_progressing(keep, follow, lateral, {})
        turning = self._largest_progressing(keep, follow, lateral, turnaround)
        if loop and (not turning or self._length(loop) >= TURNAROUND_SHARE * self._length(turning)):
            self.mode, lanes, turnaround = "loop", loop, {}
        elif turning:
            self.mode, lanes = "turnaround", turning
        else:
            self.mode, lanes = "restart", frozenset(keep)
        self.lanes = lanes
        self._sorted = sorted(lanes)
        if not self._sorted:
            raise InputError(f"the lane graph has no drivable lane of {DEGENERATE_LANE:g} m or more: "
                             "there is nowhere to drive")
        self._follow = {k: sorted(b for b in follow[k] if b in lanes) for k in self._sorted}
        self._lateral = {k: sorted(b for b in lateral[k] if b in lanes) for k in self._sorted}
        self._turnaround = {k: v[0] for k, v in turnaround.items() if k in lanes and v[0] in lanes}
        self._towards = self._lane_changes_to_exits()

    # ------------------------------------------------------------------ kept between drives
    @classmethod
    def cached(cls, graph: LaneGraph, lines: LaneLines, xodr, map_sha256: str, max_cut: float = MAX_CUT,
               lane_change_probability: float = 0.2) -> RandomRoutes:
        """``RandomRoutes(graph, lines, ...)``, read from the plan a drive on the same map and code saved
        (``twin.planning.route_cache``) when there is one, else computed and saved. Read back, the routes
        have no ``undrivable`` and ``transitions`` (None): the walk needs neither."""
        from twin.planning import route_cache

        path = route_cache.plan_path(xodr, map_sha256, max_cut, lane_change_probability, lines.step,
                                     graph.lane_types)
        if path is None:
            return cls(graph, lines, max_cut, lane_change_probability)
        plan = route_cache.load_plan(path, graph)
        if plan is not None:
            with collector_paused():  # a dict and lists per lane, no cycles
                return cls.from_plan(graph, lines, plan, lane_change_probability)
        routes = cls(graph, lines, max_cut, lane_change_probability)
        route_cache.save_plan(path, {**routes.plan(), **route_cache.graph_arrays(graph),
                                     "graph": np.array(route_cache.keys_digest(graph))})
        return routes

    def plan(self) -> dict[str, np.ndarray]:
        """What the walk needs, by node number of the lane graph (``from_plan`` reads it back)."""
        graph = self.graph

        def nodes(keys):
            return np.array([graph.node(k) for k in keys], dtype=np.int64)

        def table(mapping, owners):
            lists = [mapping[k] for k in owners]
            return np.r_[0, np.cumsum([len(v) for v in lists])].astype(np.int64), nodes(k for v in lists for k in v)

        follow_at, follow = table(self._follow, self._sorted)
        lateral_at, lateral = table(self._lateral, self._sorted)
        towards_from = list(self._towards)
        towards_at, towards = table(self._towards, towards_from)
        return {"mode": np.array(self.mode), "lanes": nodes(self._sorted),
                "length": np.array([self.lines.length(k) for k in self._sorted], dtype=np.float64),
                "follow_at": follow_at, "follow": follow, "lateral_at": lateral_at, "lateral": lateral,
                "towards_from": nodes(towards_from), "towards_at": towards_at, "towards": towards,
                "turnaround_from": nodes(self._turnaround), "turnaround_to": nodes(self._turnaround.values())}

    @classmethod
    def from_plan(cls, graph: LaneGraph, lines: LaneLines, plan: dict,
                  lane_change_probability: float = 0.2) -> RandomRoutes:
        """The routes of a saved ``plan``; the lanes' lengths are handed to ``lines`` (no line is built)."""
        routes = cls.__new__(cls)
        routes.graph, routes.lines = graph, lines
        routes.lane_change_probability = lane_change_probability
        routes.undrivable = routes.transitions = None
        keys = graph.keys

        def lanes(nodes):
            return [keys[i] for i in nodes.tolist()]

        def table(owners, at, targets):
            targets = lanes(targets)
            at = at.tolist()
            return {k: targets[at[i]:at[i + 1]] for i, k in enumerate(owners)}

        routes.mode = str(plan["mode"])
        routes._sorted = lanes(plan["lanes"])
        routes.lanes = frozenset(routes._sorted)
        lines.remember_lengths(routes._sorted, plan["length"].tolist())
        routes._follow = table(routes._sorted, plan["follow_at"], plan["follow"])
        routes._lateral = table(routes._sorted, plan["lateral_at"], plan["lateral"])
        routes._turnaround = dict(zip(lanes(plan["turnaround_from"]), lanes(plan["turnaround_to"])))
        routes._towards = table(lanes(plan["towards_from"]), plan["towards_at"], plan["towards"])
        return routes

    # ------------------------------------------------------------------ construction
    @staticmethod
    def _by_section(keep) -> dict[tuple[int, int], list[LaneKey]]:
        by_section: dict[tuple[int, int], list[LaneKey]] = {}
        for key in sorted(keep):
            by_section.setdefault((key.road_index, key.section_index), []).append(key)
        return by_section

    def _turnaround_target(self, key: LaneKey, keep, by_section) -> LaneKey | None:
        """Where a car at the end of dead-end lane ``key`` turns around: the nearest drivable lane of the
        opposite direction that netconvert's turnaround from the lane's end leads into (a U-turn the car
        cannot drive in lane), or that enters the same lane section at its end; None without one.
        ``by_section``: ``_by_section`` of ``keep`` or of more lanes (only those in ``keep`` count)."""
        graph, lines = self.graph, self.lines
        forward = graph.drives_with_s(key)
        targets = {k for k in self.transitions.u_turn[key] if k in keep}
        targets.update(k for k in by_section.get((key.road_index, key.section_index), ())
                       if k in keep and graph.drives_with_s(k) is not forward)
        if not targets:
            return None
        end = lines.ends(key).tail[-1]
        return min(targets, key=lambda k: (float(np.hypot(*(lines.ends(k).head[0] - end))), k))

    def _turnarounds(self, keep: set[LaneKey], follow: dict, by_section: dict) -> dict[LaneKey, list[LaneKey]]:
        """Dead-end lane -> [where a car turns around (``_turnaround_target``)]."""
        found = {}
        for key in sorted(keep):
            if not follow[key]:
                target = self._turnaround_target(key, keep, by_section)
                if target is not None:
                    found[key] = [target]
        return found

    def _without_blocked_ends(self, keep: set[LaneKey], follow: dict, lateral: dict,
                              by_section: dict) -> set[LaneKey]:
        """``keep`` without the lanes that lead only into dead ends of our own making. A lane the map leads
        on from, but only through a bend the car cannot drive (``Transitions.blocked``), or only into lanes
        dropped here, is dropped when it has no lane to turn around into and no lane change towards a lane
        that drives on. A walk that entered it would stop in the middle of a junction and restart there
        (Taipei: a left turn that netconvert splits over two junctions, the second turning a right angle on
        the spot). Lanes where the map itself ends stay: that is where restarts and turnarounds belong.
        Only walks without a closed loop can reach such lanes: the loop and turnaround components keep a
        way on for every lane by construction."""
        keep = set(keep)
        blocked = self.transitions.blocked

        def map_ends(k):
            return not follow[k] and k not in blocked

        def drives_on(k, by_section):
            if any(b in keep for b in follow[k]) or map_ends(k):
                return True
            return self._turnaround_target(k, keep, by_section) is not None

        while True:
            stuck = [k for k in sorted(keep) if not drives_on(k, by_section)]
            # a lane change towards a lane that drives on is a way on, too (runs of changes stay in a section)
            dropped = []
            for k in stuck:
                seen, queue = {k}, deque([k])
                found = False
                while queue and not found:
                    for b in lateral[queue.popleft()]:
                        if b in keep and b not in seen:
                            if drives_on(b, by_section):
                                found = True
                                break
                            seen.add(b)
                            queue.append(b)
                if not found:
                    dropped.append(k)
            if not dropped:
                return keep
            keep.difference_update(dropped)

    def _length(self, lanes) -> float:
        return float(sum(self.lines.length(k) for k in lanes))

    def _largest_progressing(self, keep, follow, lateral, turnaround) -> frozenset | None:
        """The longest strongly connected set of lanes (follow, lane-change and the given turnaround edges)
        with a cycle that covers distance: a follow or turnaround edge inside the set (every lane here is at
        least ``DEGENERATE_LANE`` long). Lane-change-only cycles never qualify."""
        lanes = sorted(keep)
        node = {k: i for i, k in enumerate(lanes)}
        forward = [(node[a], node[b]) for a in lanes for b in follow[a] + turnaround.get(a, [])]
        edges = forward + [(node[a], node[b]) for a in lanes for b in lateral[a]]
        source, target = (np.array(column, dtype=np.int64) for column in zip(*edges)) if edges else ((), ())
        _, label = strong_components(len(lanes), source, target)
        # components with a follow or turnaround edge inside (the first len(forward) edges), members in order
        inside = label[source[:len(forward)]] == label[target[:len(forward)]] if forward else np.zeros(0, bool)
        progressing = np.unique(label[source[:len(forward)][inside]]).tolist() if forward else []
        member = np.isin(label, progressing)
        order = np.flatnonzero(member)[np.argsort(label[member], kind="stable")]
        bounds = np.searchsorted(label[order], progressing + [np.inf])
        members = {i: [lanes[k] for k in order[lo:hi].tolist()]
                   for i, lo, hi in zip(progressing, bounds[:-1].tolist(), bounds[1:].tolist())}
        best, best_rank = None, None
        for i in progressing:
            component = frozenset(members[i])
            rank = (self._length(component), len(component), min(component))
            if best_rank is None or rank > best_rank:
                best, best_rank = component, rank
        return best

    def _lane_changes_to_exits(self) -> dict[LaneKey, list[LaneKey]]:
        """For lanes without a follow edge: the lane changes that lead, by the fewest changes, to a lane that
        drives on (a follow edge, else a turnaround). Lanes that lead nowhere are dead ends (restart)."""
        towards: dict[LaneKey, list[LaneKey]] = {}
        changes_in = {k: [] for k in self._sorted}
        for a in self._sorted:
            for b in self._lateral[a]:
                changes_in[b].append(a)
        driving_on = [k for k in self._sorted if self._follow[k]]
        turning = [k for k in self._sorted if k in self._turnaround]
        for exits in (driving_on, turning):
            distance = {k: 0 for k in exits}
            queue = deque(exits)
            while queue:
                b = queue.popleft()
                for a in sorted(changes_in[b]):
                    if a not in distance and a not in towards and not self._follow[a]:
                        distance[a] = distance[b] + 1
                        queue.append(a)
            for a, d in distance.items():
                if d > 0:
                    towards[a] = sorted(b for b in self._lateral[a] if distance.get(b) == d - 1)
        return towards

    # ------------------------------------------------------------------ the walk
    @property
    def length(self) -> float:
        return self._length(self._sorted)

    def start_lane(self, rng: np.random.Generator) -> LaneKey:
        """A lane drawn with probability proportional to its length (so starts spread over the network)."""
        lengths = np.array([self.lines.length(k) for k in self._sorted]) + 1.0
        return self._sorted[int(rng.choice(len(self._sorted), p=lengths / lengths.sum()))]

    def next_lane(self, key: LaneKey, rng: np.random.Generator,
                  came_from: LaneKey | None = None) -> tuple[RouteBreak | None, LaneKey]:
        """(None, the lane to drive next) or (TURNAROUND / RESTART, the lane the car goes on from)."""
        follow = self._follow[key]
        if follow:
            # a voluntary lane change only into a lane that drives on, never straight back
            lateral = [k for k in self._lateral[key] if k != came_from and self._follow[k]]
            may_change = lateral and came_from is None and self.lines.length(key) >= MIN_LANE_CHANGE_LENGTH
            if may_change and rng.random() < self.lane_change_probability:
                return None, lateral[int(rng.integers(len(lateral)))]
            return None, follow[int(rng.integers(len(follow)))]
        towards = self._towards.get(key)
        if towards:
            return None, towards[int(rng.integers(len(towards)))]
        if key in self._turnaround:
            return TURNAROUND, self._turnaround[key]
        return RESTART, self.start_lane(rng)

    def walk(self, rng: np.random.Generator, start: LaneKey | None = None) -> Iterator[LaneKey | RouteBreak]:
        """Lanes in driving order, endless; a ``RouteBreak`` before the lane a turnaround or restart goes on
        from."""
        key = self.start_lane(rng) if start is None else start
        came_from = None
        while True:
            yield key
            jump, following = self.next_lane(key, rng, came_from)
            if jump is not None:
                yield jump
                came_from = None
            else:
                came_from = key if following in self._lateral[key] else None
            key = following

    def chunks(self, codes: LaneCodes, rng: np.random.Generator, start: LaneKey | None = None,
               start_along: float = 0.0) -> Iterator[PathChunk]:
        """An endless path from ``start`` (or a random lane), ``start_along`` metres in."""
        return expand_route(self.lines, codes, self.walk(rng, start), start_along)
