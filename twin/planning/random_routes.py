"""Random routes that never dead-end: the next lane is drawn inside the largest strongly connected part.

netconvert's turnarounds (U-turns a car cannot drive inside its lane) are removed first. Lane changes are
part of the walk, because on real networks turn lanes often make the follow-only graph fall apart. In the
largest strongly connected component every lane reaches every other, so a next lane inside it always
exists and the walk runs forever. The walk prefers driving on (follow edges); it changes lanes with
probability ``lane_change_probability`` where the lane is long enough, and whenever it has to.
"""

from __future__ import annotations

from collections.abc import Iterator

import networkx as nx
import numpy as np

from tavf_mapkit.errors import InputError
from tavf_mapkit.lanegraph import LaneGraph, LaneKey
from twin.map.lanelines import LaneLines
from twin.planning.chunks import LaneCodes, PathChunk, expand_route

U_TURN = np.radians(135.0)
MIN_LANE_CHANGE_LENGTH = 30.0  # m: shorter lanes change lanes only when they must


def drivable_lanes(graph: LaneGraph, lines: LaneLines, min_radius: float) -> set[LaneKey]:
    """Lanes without a U-turn (heading change over 135 degrees) or a bend tighter than ``min_radius``."""
    keep = set()
    for key in graph.keys:
        points = lines[key].points
        d = np.diff(points[:, :2], axis=0)
        seg = np.hypot(d[:, 0], d[:, 1])
        real = seg > 1e-3
        heading = np.unwrap(np.arctan2(d[real, 1], d[real, 0]))
        if len(heading) >= 2:
            if abs(heading[-1] - heading[0]) > U_TURN:
                continue
            spans = 0.5 * (seg[real][1:] + seg[real][:-1])
            if np.any(np.abs(np.diff(heading)) > spans / min_radius + 1e-3):
                continue
        keep.add(key)
    return keep


class RandomRoutes:
    def __init__(self, graph: LaneGraph, lines: LaneLines, min_radius: float = 3.0,
                 lane_change_probability: float = 0.2):
        self.graph = graph
        self.lines = lines
        self.lane_change_probability = lane_change_probability
        keep = drivable_lanes(graph, lines, min_radius)
        sub = nx.DiGraph()
        sub.add_nodes_from(sorted(keep))
        sub.add_edges_from((a, b, {"kind": kind}) for a, b, kind in graph.graph.edges(data="kind")
                           if a in keep and b in keep)
        components = [c for c in nx.strongly_connected_components(sub) if len(c) > 1]
        if not components:
            raise InputError("the lane graph has no closed loop of drivable lanes: random routes would dead-end")
        best = max(components, key=lambda c: (sum(graph.length(k) for k in c), len(c), min(c)))
        self.lanes = frozenset(best)
        self._sorted = sorted(self.lanes)
        self._follow: dict[LaneKey, list[LaneKey]] = {}
        self._lateral: dict[LaneKey, list[LaneKey]] = {}
        for key in self._sorted:
            out = [(b, sub.edges[key, b]["kind"]) for b in sub.successors(key) if b in self.lanes]
            self._follow[key] = sorted(b for b, kind in out if kind == "follow")
            self._lateral[key] = sorted(b for b, kind in out if kind != "follow")

    @property
    def length(self) -> float:
        return float(sum(self.graph.length(k) for k in self._sorted))

    def start_lane(self, rng: np.random.Generator) -> LaneKey:
        """A lane drawn with probability proportional to its length (so starts spread over the network)."""
        lengths = np.array([self.lines[k].length for k in self._sorted]) + 1.0
        return self._sorted[int(rng.choice(len(self._sorted), p=lengths / lengths.sum()))]

    def next_lane(self, key: LaneKey, rng: np.random.Generator, came_from: LaneKey | None = None) -> LaneKey:
        follow = self._follow[key]
        # never straight back to the lane we just changed from, unless there is nothing else
        lateral = [k for k in self._lateral[key] if k != came_from] or self._lateral[key]
        may_change = lateral and came_from is None and self.lines[key].length >= MIN_LANE_CHANGE_LENGTH
        if follow and not (may_change and rng.random() < self.lane_change_probability):
            return follow[int(rng.integers(len(follow)))]
        if not lateral:
            return follow[int(rng.integers(len(follow)))]
        return lateral[int(rng.integers(len(lateral)))]

    def walk(self, rng: np.random.Generator, start: LaneKey | None = None) -> Iterator[LaneKey]:
        key = self.start_lane(rng) if start is None else start
        came_from = None
        while True:
            yield key
            following = self.next_lane(key, rng, came_from)
            came_from = key if following in self._lateral[key] else None
            key = following

    def chunks(self, codes: LaneCodes, rng: np.random.Generator, start: LaneKey | None = None,
               start_along: float = 0.0) -> Iterator[PathChunk]:
        """An endless path from ``start`` (or a random lane), ``start_along`` metres in."""
        return expand_route(self.lines, codes, self.walk(rng, start), start_along)
