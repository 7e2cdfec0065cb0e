"""LaneGraph: a networkx.DiGraph whose nodes are lanes (LaneKey) and whose edges run in driving direction.

Edges carry ``kind`` ("follow": drive on into the next lane, "left"/"right": change lanes) and ``weight`` in
metres: a follow edge costs the length of the lane it leaves, a lane change ``lane_change_cost`` (so a route's
cost is the length driven up to the start of its last lane plus the lane changes). Node attributes:
``length`` (m, centre line), ``start`` and ``end`` (x, y of the centre line in driving direction), ``road_id``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from functools import cached_property

import networkx as nx
import numpy as np

from tavf_mapkit.errors import MapkitError
from tavf_mapkit.lanegraph.geometry import LaneTable, centre_points, section_s_values
from tavf_mapkit.lanegraph.keys import LaneKey, drives_with_s, lane_toward_minus_t, lane_toward_plus_t
from tavf_mapkit.lanegraph.lanechange import lane_change_allowed
from tavf_mapkit.lanegraph.topology import lane_end_pairs


def lane_speed_limit(road, section_index: int, lane_id: int) -> float | None:
    """m/s at the start of a lane section: the lane's speed record, else the road type's; None when unset."""
    section = road.lane_sections[section_index]
    limits = [value for s0, value in section.by_id[lane_id].speed_limits() if s0 <= section.s0 + 1e-6]
    if limits:
        return limits[-1]
    return road.speed_limit(section.s0)


class NoRouteError(MapkitError):
    """No path through the lane graph between two lanes."""


class LaneGraph:
    """Build with :meth:`from_opendrive`; the networkx graph is ``self.graph``."""

    def __init__(self, odr, graph: nx.DiGraph, lane_rows: dict[LaneKey, int], forward: dict[LaneKey, bool],
                 table: LaneTable, step: float = 1.0, lane_types: frozenset[str] = frozenset({"driving"})):
        self.odr = odr
        self.graph = graph
        self._rows = lane_rows
        self._forward = forward
        self._table = table
        self.step = step  # m between the table's centre-line samples
        self.lane_types = lane_types

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_opendrive(cls, odr, lane_types: Iterable[str] = ("driving",), lane_change_cost: float = 5.0,
                       step: float = 1.0) -> LaneGraph:
        """Nodes for the lanes of ``lane_types``; follow edges from the map's links, lane changes between
        same-direction neighbours where the road mark between them allows it."""
        arrays = odr.arrays
        types = set(lane_types)
        # the index keeps the centre-line samples of the graph's lanes only (a city's sidewalks are as many)
        table = LaneTable.build(odr, step, keep=np.isin(arrays.lane_type, sorted(types)))
        section_first = np.searchsorted(arrays.section_road, np.arange(len(odr.roads)), side="left")
        graph = nx.DiGraph()
        rows: dict[LaneKey, int] = {}
        forward: dict[LaneKey, bool] = {}
        for row in range(len(arrays.lane_id)):
            if arrays.lane_type[row] not in types:
                continue
            section = int(arrays.lane_section[row])
            road_index = int(arrays.section_road[section])
            key = LaneKey(road_index, section - int(section_first[road_index]), int(arrays.lane_id[row]))
            road = odr.roads[road_index]
            lane = road.lane_sections[key.section_index].by_id[key.lane_id]
            ahead = drives_with_s(road, lane)
            first, last = table.first[row, :2], table.last[row, :2]
            start, end = (first, last) if ahead else (last, first)
            rows[key] = row
            forward[key] = ahead
            graph.add_node(key, length=float(table.length[row]), start=(float(start[0]), float(start[1])),
                           end=(float(end[0]), float(end[1])), road_id=road.id)
        exits = {(*key, "end" if ahead else "start"): key for key, ahead in forward.items()}
        entries = {(*key, "start" if ahead else "end"): key for key, ahead in forward.items()}
        for p, q in lane_end_pairs(odr):
            for a, b in ((p, q), (q, p)):
                if a in exits and b in entries and exits[a] != entries[b]:
                    source = exits[a]
                    graph.add_edge(source, entries[b], kind="follow", weight=graph.nodes[source]["length"])
        for key, ahead in forward.items():
            road = odr.roads[key.road_index]
            section = road.lane_sections[key.section_index]
            middle = 0.5 * (section.s0 + road.section_end(key.section_index))
            plus, minus = lane_toward_plus_t(key.lane_id), lane_toward_minus_t(key.lane_id)
            # driving with s, the vehicle's left is +t; against s it is -t
            for kind, neighbour_id in (("left", plus if ahead else minus), ("right", minus if ahead else plus)):
                neighbour = LaneKey(key.road_index, key.section_index, neighbour_id)
                if forward.get(neighbour) is ahead and lane_change_allowed(section, key.lane_id, neighbour_id,
                                                                            middle):
                    graph.add_edge(key, neighbour, kind=kind, weight=float(lane_change_cost))
        return cls(odr, graph, rows, forward, table, step, frozenset(types))

    # ------------------------------------------------------------------ queries
    def __contains__(self, key) -> bool:
        return key in self._rows

    def __len__(self) -> int:
        return self.graph.number_of_nodes()

    @property
    def keys(self) -> list[LaneKey]:
        return list(self._rows)

    def drives_with_s(self, key: LaneKey) -> bool:
        return self._forward[key]

    def length(self, key: LaneKey) -> float:
        """Length of the lane's centre line (m)."""
        return self.graph.nodes[key]["length"]

    def road_id(self, key: LaneKey) -> str:
        return self.odr.roads[key.road_index].id

    def successors(self, key: LaneKey) -> list[LaneKey]:
        """Lanes the lane leads into (follow edges only), sorted for determinism."""
        return sorted(k for k, data in self.graph.adj[key].items() if data["kind"] == "follow")

    def predecessors(self, key: LaneKey) -> list[LaneKey]:
        return sorted(k for k in self.graph.predecessors(key) if self.graph.edges[k, key]["kind"] == "follow")

    def neighbours(self, key: LaneKey) -> tuple[LaneKey | None, LaneKey | None]:
        """(left, right) same-direction neighbours in driving direction, whether or not a change is allowed."""
        ahead = self._forward[key]
        plus = LaneKey(key.road_index, key.section_index, lane_toward_plus_t(key.lane_id))
        minus = LaneKey(key.road_index, key.section_index, lane_toward_minus_t(key.lane_id))
        left, right = (plus, minus) if ahead else (minus, plus)
        same = [k if self._forward.get(k) is ahead else None for k in (left, right)]
        return same[0], same[1]

    def lane_change_allowed(self, key: LaneKey, side: str) -> bool:
        """May a vehicle change from ``key`` to its ``side`` ("left"/"right") neighbour?"""
        left, right = self.neighbours(key)
        target = left if side == "left" else right
        return target is not None and self.graph.has_edge(key, target)

    def speed_limit(self, key: LaneKey) -> float | None:
        """m/s from the lane's speed record, else the road type's; None when the map sets none."""
        return lane_speed_limit(self.odr.roads[key.road_index], key.section_index, key.lane_id)

    def centerline(self, key: LaneKey, step: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
        """(points (N, 3), road s (N,)) of the lane centre in driving direction, at most ``step`` apart."""
        road = self.odr.roads[key.road_index]
        s = section_s_values(road.lane_sections[key.section_index].s0, road.section_end(key.section_index), step)
        points = centre_points(self.odr, np.full(len(s), self._rows[key]), s)
        if not self._forward[key]:
            points, s = points[::-1], s[::-1]
        return points, s

    def centerlines(self, keys: Iterable[LaneKey], step: float = 1.0) -> dict[LaneKey, tuple[np.ndarray, np.ndarray]]:
        """``centerline`` of many lanes in one evaluation of the map (the same points, much faster)."""
        keys = list(keys)
        if not keys:
            return {}
        values = []
        for key in keys:
            road = self.odr.roads[key.road_index]
            values.append(section_s_values(road.lane_sections[key.section_index].s0,
                                           road.section_end(key.section_index), step))
        counts = [len(v) for v in values]
        rows = np.repeat([self._rows[k] for k in keys], counts)
        points = np.split(centre_points(self.odr, rows, np.concatenate(values)), np.cumsum(counts)[:-1])
        found = {}
        for key, p, s in zip(keys, points, values):
            found[key] = (p, s) if self._forward[key] else (p[::-1], s[::-1])
        return found

    # ------------------------------------------------------------------ routing
    def shortest_path(self, a: LaneKey, b: LaneKey) -> list[LaneKey]:
        """Lanes from ``a`` to ``b`` (both included) with the least cost, by A* with a Euclidean heuristic."""
        if a not in self._rows or b not in self._rows:
            missing = a if a not in self._rows else b
            raise NoRouteError(f"lane {tuple(missing)} is not in the lane graph")
        target = np.asarray(self.graph.nodes[b]["start"])
        nodes = self.graph.nodes
        # straight-line distance between lane starts never exceeds the driven distance (lane changes cost at
        # least a lane width), so A* stays exact
        try:
            return nx.astar_path(self.graph, a, b, heuristic=lambda u, _v: math.dist(nodes[u]["start"], target),
                                 weight="weight")
        except nx.NetworkXNoPath:
            raise NoRouteError(f"no route from lane {tuple(a)} to lane {tuple(b)}") from None

    def largest_strongly_connected(self) -> frozenset:
        """The biggest set of lanes from which every other lane of the set can be reached (by lane length)."""
        components = list(nx.strongly_connected_components(self.graph))
        if not components:
            return frozenset()
        return frozenset(max(components, key=lambda c: (sum(self.length(k) for k in c), len(c), min(c))))

    def locator(self):
        """A ``LaneLocator`` over the graph's lane-centre samples: ``LaneLocator(odr, step, lane_types)`` with
        the graph's step and lane types gives the same, but samples the whole map again at once (on a region
        more than one allocation may hold)."""
        from tavf_mapkit.opendrive.locate import LaneLocator

        table = self._table
        return LaneLocator.from_samples(self.odr, table.sample_row, table.sample_s, table.sample_xy)

    @cached_property
    def total_length(self) -> float:
        return float(sum(self.length(k) for k in self._rows))
