"""LaneGraph: a directed graph whose nodes are lanes (LaneKey) and whose edges run in driving direction.

Edges carry a kind ("follow": drive on into the next lane, "left"/"right": change lanes) and a weight in
metres: a follow edge costs the length of the lane it leaves, a lane change ``lane_change_cost`` (so a route's
cost is the length driven up to the start of its last lane plus the lane changes). Per lane: ``length`` (m,
centre line), ``start`` and ``end`` (x, y of the centre line in driving direction), ``road_id``. The edges are
arrays (``lanegraph.edges``), routing gives exactly the routes networkx gave on the same graph.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable
from functools import cached_property

import numpy as np

from tavf_mapkit.errors import MapkitError
from tavf_mapkit.lanegraph.edges import FOLLOW, KIND_NAMES, LEFT, RIGHT, EdgeArrays, euclidean
from tavf_mapkit.lanegraph.geometry import (
    LaneTable,
    centre_points,
    lane_samples,
    section_centre_lines,
    section_s_values,
)
from tavf_mapkit.lanegraph.keys import LaneKey, drives_with_s, lane_toward_minus_t, lane_toward_plus_t
from tavf_mapkit.lanegraph.lanechange import lane_change_allowed
from tavf_mapkit.lanegraph.topology import lane_end_pairs
from tavf_mapkit.memory import collector_paused


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
    """Build with :meth:`from_opendrive`. Lanes are numbered in the map's row order (``keys``); their edges
    are arrays (``edges``, an ``EdgeArrays``): a region's graph is a few MB, not a dict per lane and edge."""

    def __init__(self, odr, keys: list[LaneKey], lane_rows: np.ndarray, forward: np.ndarray, edges: EdgeArrays,
                 table: LaneTable | None = None, step: float = 1.0,
                 lane_types: frozenset[str] = frozenset({"driving"})):
        self.odr = odr
        self._keys = keys
        self._index = {key: i for i, key in enumerate(keys)}
        self._row = np.asarray(lane_rows, dtype=np.int64)  # the lane's row of odr.arrays
        self._ahead = forward  # drives with s
        # the edges as built; a follow edge's weight may be NaN until the lane lengths are known (``edges``)
        self._topology = edges
        if table is not None:
            self.__dict__["_table"] = table
        self.step = step  # m between the table's centre-line samples
        self.lane_types = lane_types

    # the lane table (lengths, end points, boxes: every lane sampled at ``step``) is built when first asked
    # for: a random drive needs only the graph's topology at its start, and on a region the table is the
    # largest part of the graph (59,133 roads: some 10 s)
    @cached_property
    def _table(self) -> LaneTable:
        return LaneTable.build(self.odr, self.step, keep_samples=False)

    @cached_property
    def _length(self) -> np.ndarray:
        return np.asarray(self._table.length[self._row], dtype=np.float64)

    @cached_property
    def _start(self) -> np.ndarray:
        """The centre line's start in driving direction, per lane."""
        first, last = self._table.first[self._row, :2], self._table.last[self._row, :2]
        return np.where(self._ahead[:, None], first, last)

    @cached_property
    def _end(self) -> np.ndarray:
        first, last = self._table.first[self._row, :2], self._table.last[self._row, :2]
        return np.where(self._ahead[:, None], last, first)

    @cached_property
    def edges(self) -> EdgeArrays:
        """The edges with their weights: a follow edge costs the length of the lane it leaves (filled in here,
        on first use, where ``from_opendrive`` left them NaN)."""
        topology = self._topology
        unknown = np.isnan(topology.weight)
        if not np.any(unknown):
            return topology
        weight = topology.weight.copy()
        weight[unknown] = self._length[topology.source[unknown]]
        return EdgeArrays(topology.n, topology.indptr, topology.target, topology.kind, weight)

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_opendrive(cls, odr, lane_types: Iterable[str] = ("driving",), lane_change_cost: float = 5.0,
                       step: float = 1.0) -> LaneGraph:
        """Nodes for the lanes of ``lane_types``; follow edges from the map's links, lane changes between
        same-direction neighbours where the road mark between them allows it."""
        # a key, a list entry and a dict entry per lane and link, next to no cycles: the collector's passes would
        # only walk them again and again (and the loaded map, unless frozen)
        with collector_paused():
            return cls._from_opendrive(odr, lane_types, lane_change_cost, step)

    @classmethod
    def _from_opendrive(cls, odr, lane_types: Iterable[str], lane_change_cost: float, step: float) -> LaneGraph:
        arrays = odr.arrays
        types = set(lane_types)
        section_first = np.searchsorted(arrays.section_road, np.arange(len(odr.roads)), side="left")
        keys: list[LaneKey] = []
        rows: list[int] = []
        ahead: list[bool] = []
        for row in range(len(arrays.lane_id)):
            if arrays.lane_type[row] not in types:
                continue
            section = int(arrays.lane_section[row])
            road_index = int(arrays.section_road[section])
            key = LaneKey(road_index, section - int(section_first[road_index]), int(arrays.lane_id[row]))
            road = odr.roads[road_index]
            lane = road.lane_sections[key.section_index].by_id[key.lane_id]
            keys.append(key)
            rows.append(row)
            ahead.append(drives_with_s(road, lane))
        index = {key: i for i, key in enumerate(keys)}
        # edges in the order networkx's graph had them (routing's tie-breaks depend on it): follow edges in
        # the order of the map's links, then the lane changes lane by lane
        source: list[int] = []
        target: list[int] = []
        kind: list[int] = []
        exits = {(*key, "end" if forward else "start"): i for i, (key, forward) in enumerate(zip(keys, ahead))}
        entries = {(*key, "start" if forward else "end"): i for i, (key, forward) in enumerate(zip(keys, ahead))}
        for p, q in lane_end_pairs(odr):
            for a, b in ((p, q), (q, p)):
                i, j = exits.get(a), entries.get(b)
                if i is not None and j is not None and i != j:
                    source.append(i)
                    target.append(j)
        del exits, entries
        # a follow edge costs the lane it leaves: NaN until the lengths are known (``edges``)
        weight = [np.nan] * len(source)
        kind = [FOLLOW] * len(source)
        for i, (key, forward) in enumerate(zip(keys, ahead)):
            road = odr.roads[key.road_index]
            section = road.lane_sections[key.section_index]
            middle = 0.5 * (section.s0 + road.section_end(key.section_index))
            plus, minus = lane_toward_plus_t(key.lane_id), lane_toward_minus_t(key.lane_id)
            # driving with s, the vehicle's left is +t; against s it is -t
            for code, neighbour_id in ((LEFT, plus if forward else minus), (RIGHT, minus if forward else plus)):
                j = index.get(LaneKey(key.road_index, key.section_index, neighbour_id))
                if j is not None and ahead[j] is forward and lane_change_allowed(section, key.lane_id,
                                                                                  neighbour_id, middle):
                    source.append(i)
                    target.append(j)
                    kind.append(code)
                    weight.append(float(lane_change_cost))
        edges = EdgeArrays.from_edges(len(keys), source, target, kind, weight)
        return cls(odr, keys, np.asarray(rows, dtype=np.int64), np.asarray(ahead, dtype=bool), edges, None, step,
                   frozenset(types))

    def to_networkx(self):
        """The graph as a ``networkx.DiGraph`` (lanes with ``length``, ``start``, ``end``, ``road_id``; edges with
        ``kind`` and ``weight``), for tools and tests; the twin never needs it."""
        import networkx as nx

        graph = nx.DiGraph()
        for key in self._keys:
            graph.add_node(key, length=self.length(key), start=self.start(key), end=self.end(key),
                           road_id=self.road_id(key))
        keys, edges = self._keys, self.edges
        for e, (i, j) in enumerate(zip(edges.source.tolist(), edges.target.tolist())):
            graph.add_edge(keys[i], keys[j], kind=KIND_NAMES[edges.kind[e]], weight=float(edges.weight[e]))
        return graph

    # ------------------------------------------------------------------ lanes
    def __contains__(self, key) -> bool:
        return key in self._index

    def __len__(self) -> int:
        return len(self._keys)

    @property
    def keys(self) -> list[LaneKey]:
        """The lanes in node order (the map's row order)."""
        return list(self._keys)

    @cached_property
    def key_array(self) -> np.ndarray:
        """The keys in node order as an (n, 3) int64 array (road index, section index, lane id)."""
        flat = np.fromiter(itertools.chain.from_iterable(self._keys), dtype=np.int64, count=3 * len(self._keys))
        return flat.reshape(-1, 3)

    def node(self, key: LaneKey) -> int:
        """The lane's node number (its position in ``keys``, the rows of ``edges``)."""
        return self._index[key]

    def key(self, node: int) -> LaneKey:
        return self._keys[node]

    def row(self, key: LaneKey) -> int:
        """The lane's row of ``odr.arrays``."""
        return int(self._row[self._index[key]])

    def drives_with_s(self, key: LaneKey) -> bool:
        return bool(self._ahead[self._index[key]])

    def length(self, key: LaneKey) -> float:
        """Length of the lane's centre line (m)."""
        return float(self._length[self._index[key]])

    def start(self, key: LaneKey) -> tuple[float, float]:
        """(x, y) where the lane's centre line starts, in driving direction."""
        x, y = self._start[self._index[key]]
        return float(x), float(y)

    def end(self, key: LaneKey) -> tuple[float, float]:
        x, y = self._end[self._index[key]]
        return float(x), float(y)

    def road_id(self, key: LaneKey) -> str:
        return self.odr.roads[key.road_index].id

    # ------------------------------------------------------------------ edges
    def edge_list(self) -> list[tuple[LaneKey, LaneKey, str]]:
        """Every edge as (from, to, kind), lane by lane in node order, each lane's edges in the order added."""
        keys, edges = self._keys, self._topology
        kinds = [KIND_NAMES[k] for k in edges.kind.tolist()]
        return [(keys[i], keys[j], kind) for i, j, kind in zip(edges.source.tolist(), edges.target.tolist(), kinds)]

    def out_edges(self, key: LaneKey) -> list[tuple[LaneKey, str, float]]:
        """(to, kind, weight) of the lane's edges, in the order they were added."""
        edges = self.edges
        return [(self._keys[int(edges.target[e])], KIND_NAMES[edges.kind[e]], float(edges.weight[e]))
                for e in edges.row(self._index[key])]

    def edge_kind(self, a: LaneKey, b: LaneKey) -> str | None:
        """"follow", "left" or "right" for the edge a -> b; None without one."""
        i, j = self._index.get(a), self._index.get(b)
        if i is None or j is None:
            return None
        e = self._topology.find(i, j)
        return None if e < 0 else KIND_NAMES[self._topology.kind[e]]

    def has_edge(self, a: LaneKey, b: LaneKey) -> bool:
        return self.edge_kind(a, b) is not None

    def edge_weight(self, a: LaneKey, b: LaneKey) -> float:
        """Cost of the edge a -> b in metres (KeyError without one)."""
        e = self.edges.find(self._index[a], self._index[b])
        if e < 0:
            raise KeyError((a, b))
        return float(self.edges.weight[e])

    def path_cost(self, path: list[LaneKey]) -> float:
        """Sum of the edge weights along ``path`` (consecutive lanes joined by edges), in path order."""
        return sum(self.edge_weight(a, b) for a, b in zip(path, path[1:]))

    def successors(self, key: LaneKey) -> list[LaneKey]:
        """Lanes the lane leads into (follow edges only), sorted for determinism."""
        indptr, target, kind, _ = self._topology.lists
        i = self._index[key]
        return sorted(self._keys[target[e]] for e in range(indptr[i], indptr[i + 1]) if kind[e] == FOLLOW)

    def follow_edges(self) -> tuple[np.ndarray, np.ndarray]:
        """(source, target) node numbers of every follow edge (row order): ``successors`` of all lanes at once."""
        topology = self._topology
        follow = topology.kind == FOLLOW
        return topology.source[follow], topology.target[follow]

    def lane_changes(self, key: LaneKey) -> list[LaneKey]:
        """Lanes the lane may change into (left/right edges), in the order added."""
        indptr, target, kind, _ = self._topology.lists
        i = self._index[key]
        return [self._keys[target[e]] for e in range(indptr[i], indptr[i + 1]) if kind[e] != FOLLOW]

    def predecessors(self, key: LaneKey) -> list[LaneKey]:
        """Lanes that lead into the lane (follow edges only), sorted."""
        edges = self._topology
        indptr, incoming = edges.incoming
        j = self._index[key]
        found = incoming[indptr[j]:indptr[j + 1]]
        found = found[edges.kind[found] == FOLLOW]
        return sorted(self._keys[int(i)] for i in edges.source[found])

    def neighbours(self, key: LaneKey) -> tuple[LaneKey | None, LaneKey | None]:
        """(left, right) same-direction neighbours in driving direction, whether or not a change is allowed."""
        ahead = self.drives_with_s(key)
        plus = LaneKey(key.road_index, key.section_index, lane_toward_plus_t(key.lane_id))
        minus = LaneKey(key.road_index, key.section_index, lane_toward_minus_t(key.lane_id))
        left, right = (plus, minus) if ahead else (minus, plus)
        same = [k if k in self._index and self.drives_with_s(k) is ahead else None for k in (left, right)]
        return same[0], same[1]

    def lane_change_allowed(self, key: LaneKey, side: str) -> bool:
        """May a vehicle change from ``key`` to its ``side`` ("left"/"right") neighbour?"""
        left, right = self.neighbours(key)
        target = left if side == "left" else right
        return target is not None and self.has_edge(key, target)

    def speed_limit(self, key: LaneKey) -> float | None:
        """m/s from the lane's speed record, else the road type's; None when the map sets none."""
        return lane_speed_limit(self.odr.roads[key.road_index], key.section_index, key.lane_id)

    def centerline(self, key: LaneKey, step: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
        """(points (N, 3), road s (N,)) of the lane centre in driving direction, at most ``step`` apart."""
        road = self.odr.roads[key.road_index]
        s0, s1 = road.lane_sections[key.section_index].s0, road.section_end(key.section_index)
        self.odr.arrays.budget.check([key.road_index], [max(np.ceil((s1 - s0) / step), 1) + 1], "a lane centre line")
        s = section_s_values(s0, s1, step)
        points = centre_points(self.odr, np.full(len(s), self.row(key)), s)
        if not self.drives_with_s(key):
            points, s = points[::-1], s[::-1]
        return points, s

    def centerlines(self, keys: Iterable[LaneKey], step: float = 1.0) -> dict[LaneKey, tuple[np.ndarray, np.ndarray]]:
        """``centerline`` of many lanes in one evaluation of the map (the same points, much faster)."""
        keys = list(keys)
        points, s, counts = self.centerline_arrays(keys, step)
        cuts = np.cumsum(counts)[:-1]
        return dict(zip(keys, zip(np.split(points, cuts), np.split(s, cuts))))

    def centerline_arrays(self, keys: list[LaneKey], step: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``centerline`` of many lanes as flat arrays: (points (n, 3), road s (n,), points per lane), lane after
        lane in the order of ``keys``, each in driving direction; the same numbers, to the bit."""
        nodes = np.fromiter((self._index[k] for k in keys), dtype=np.int64, count=len(keys))
        rows = self._row[nodes]
        arrays = self.odr.arrays
        section = arrays.lane_section[rows]
        s0, s1 = arrays.section_s0[section], arrays.section_end[section]
        # asked before allocating: one absurd @length would be billions of points (the map's budget says
        # which road, in one line)
        arrays.budget.check(arrays.section_road[section], np.maximum(np.ceil((s1 - s0) / step), 1) + 1,
                            "lane centre lines")
        points, s, counts = section_centre_lines(self.odr, rows, step)
        # lanes against s: their run of samples reversed
        first = np.cumsum(counts) - counts
        lane = np.repeat(np.arange(len(keys)), counts)
        within = np.arange(len(s)) - first[lane]
        backwards = ~self._ahead[nodes][lane]
        order = np.where(backwards, first[lane] + counts[lane] - 1 - within, np.arange(len(s)))
        return points[order], s[order], counts

    # ------------------------------------------------------------------ routing
    def shortest_path(self, a: LaneKey, b: LaneKey) -> list[LaneKey]:
        """Lanes from ``a`` to ``b`` (both included) with the least cost, by A* with a Euclidean heuristic."""
        if a not in self._index or b not in self._index:
            missing = a if a not in self._index else b
            raise NoRouteError(f"lane {tuple(missing)} is not in the lane graph")
        # straight-line distance between lane starts never exceeds the driven distance (lane changes cost at
        # least a lane width), so A* stays exact
        goal = self._index[b]
        path = self.edges.astar(self._index[a], goal, euclidean(self._start_list, goal))
        if path is None:
            raise NoRouteError(f"no route from lane {tuple(a)} to lane {tuple(b)}")
        return [self._keys[i] for i in path]

    @cached_property
    def _start_list(self) -> list:
        return self._start.tolist()

    def distances_from(self, key: LaneKey, cutoff: float | None = None) -> dict[LaneKey, float]:
        """Cost of the cheapest route from ``key`` to every lane it reaches within ``cutoff`` metres (``key``
        itself: 0), in the order Dijkstra settles them."""
        dist, _ = self.edges.distances(self._index[key], cutoff)
        keys = self._keys
        return {keys[i]: d for i, d in dist.items()}

    def routes_from(self, key: LaneKey, cutoff: float | None = None) -> tuple[dict[LaneKey, float],
                                                                           dict[LaneKey, list[LaneKey]]]:
        """(``distances_from``, the cheapest route to each of those lanes, ``key`` and the lane included), as
        ``networkx.single_source_dijkstra`` gives them."""
        source = self._index[key]
        dist, before = self.edges.distances(source, cutoff)
        keys = self._keys
        paths: dict[LaneKey, list[LaneKey]] = {key: [key]}
        node_paths: dict[int, list[int]] = {source: [source]}
        for i in dist:
            if i != source:
                node_paths[i] = node_paths[before[i]] + [i]
                paths[keys[i]] = [keys[n] for n in node_paths[i]]
        return {keys[i]: d for i, d in dist.items()}, paths

    def strongly_connected_components(self) -> list[frozenset]:
        """Every set of lanes from which each lane of the set can reach the others."""
        count_, labels = self._topology.strong_labels()
        members: list[list[LaneKey]] = [[] for _ in range(count_)]
        for key, label in zip(self._keys, labels.tolist()):
            members[label].append(key)
        return [frozenset(m) for m in members]

    def largest_strongly_connected(self) -> frozenset:
        """The biggest set of lanes from which every other lane of the set can be reached (by lane length)."""
        components = self.strongly_connected_components()
        if not components:
            return frozenset()
        return frozenset(max(components, key=lambda c: (sum(self.length(k) for k in c), len(c), min(c))))

    def samples(self, rows: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(lane-table row, road s, plan-view point) of the centre-line samples at the graph's step of its lanes
        (or of the lane-table rows in the mask ``rows``), sorted by row then s; evaluated when asked, not kept
        (a region's are 200 MB)."""
        wanted = np.zeros(len(self.odr.arrays.lane_id), dtype=bool)
        wanted[self._row] = True
        if rows is not None:
            wanted &= rows
        return lane_samples(self.odr, self.step, wanted)

    def locator(self, near: tuple[np.ndarray, np.ndarray] | None = None, candidates: int = 16,
                margin: float = 100.0):
        """A ``LaneLocator`` over the graph's lane-centre samples: ``LaneLocator(odr, step, lane_types)`` with
        the graph's step and lane types gives the same, but samples the whole map at once (on a region more
        than one allocation may hold).

        ``near=(x, y)``: a locator only for those points (a drive's trajectory), over the samples of the lanes
        whose centre lines come into their bounding box widened until every point's ``candidates`` nearest
        samples lie inside it; it locates them as the whole map's locator does (a sample left out lies outside
        the box, farther from every point than the box's margin, and so than each point's ``candidates``-th
        nearest kept one). A region's 7 million samples make a tree of some 200 MB; a drive's neighbourhood,
        a few thousand samples."""
        from tavf_mapkit.opendrive.locate import LaneLocator

        box = self._table.box
        mine = np.zeros(len(box), dtype=bool)
        mine[self._row] = True
        if near is not None and len(np.atleast_1d(near[0])):
            points = np.column_stack([np.atleast_1d(near[0]), np.atleast_1d(near[1])]).astype(float)
            low, high = points.min(axis=0), points.max(axis=0)
            while np.all(np.isfinite(points)):
                rows = mine & (box[:, 2] >= low[0] - margin) & (box[:, 0] <= high[0] + margin) & \
                    (box[:, 3] >= low[1] - margin) & (box[:, 1] <= high[1] + margin)
                if np.array_equal(rows, mine):
                    break
                row, s, xy = self.samples(rows)
                if len(s) >= candidates:
                    inside = np.all((xy >= low - margin) & (xy <= high + margin), axis=1)
                    locator = LaneLocator.from_samples(self.odr, row[inside], s[inside], xy[inside])
                    if np.count_nonzero(inside) >= candidates:
                        distance, _ = locator.tree.query(points, k=candidates)
                        if float(np.max(distance[:, -1])) < margin:
                            return locator
                margin *= 4.0
        return LaneLocator.from_samples(self.odr, *self.samples())

    @cached_property
    def total_length(self) -> float:
        return float(sum(self._length.tolist()))
