"""The lane graph as arrays gives exactly what the networkx graph it replaced gave: the same edges in the same
order, the same strongly connected components, the same routes (also where several routes cost the same)."""

from __future__ import annotations

import itertools
import math

import networkx as nx
import numpy as np
import pytest

from tavf_mapkit.lanegraph import LaneGraph, LaneKey
from tavf_mapkit.lanegraph.edges import KIND_NAMES, EdgeArrays, route_to, strong_components
from tavf_mapkit.lanegraph.keys import drives_with_s, lane_toward_minus_t, lane_toward_plus_t
from tavf_mapkit.lanegraph.lanechange import lane_change_allowed
from tavf_mapkit.lanegraph.topology import lane_end_pairs
from tavf_mapkit.opendrive import load_opendrive


def _random_graph(seed: int, n: int = 60, m: int = 260):
    """Edges with repeats (a later add changes kind and weight, as add_edge does) and small integer weights,
    so that many routes tie."""
    rng = np.random.default_rng(seed)
    source = rng.integers(0, n, m)
    target = rng.integers(0, n, m)
    keep = source != target
    source, target = source[keep], target[keep]
    kind = rng.integers(0, 3, len(source))
    weight = rng.integers(1, 4, len(source)).astype(float)
    reference = nx.DiGraph()
    reference.add_nodes_from(range(n))
    for a, b, k, w in zip(source.tolist(), target.tolist(), kind.tolist(), weight.tolist()):
        reference.add_edge(a, b, kind=KIND_NAMES[k], weight=w)
    return EdgeArrays.from_edges(n, source, target, kind, weight), reference


@pytest.mark.parametrize("seed", range(6))
def test_edge_arrays_search_like_networkx_on_graphs_full_of_ties(seed):
    edges, reference = _random_graph(seed)
    ours = [(int(a), int(b), KIND_NAMES[k], float(w))
            for a, b, k, w in zip(edges.source, edges.target, edges.kind, edges.weight)]
    assert ours == [(a, b, d["kind"], d["weight"]) for a, b, d in reference.edges(data=True)]
    count_, labels = edges.strong_labels()
    components = {frozenset(np.flatnonzero(labels == i).tolist()) for i in range(count_)}
    assert components == {frozenset(c) for c in nx.strongly_connected_components(reference)}
    heuristic = np.random.default_rng(seed + 100).uniform(0.0, 1.0, edges.n).tolist()  # admissible: weights >= 1
    for source in range(0, edges.n, 7):
        for cutoff in (None, 4.0):
            dist, before = edges.distances(source, cutoff)
            want_dist, want_paths = nx.single_source_dijkstra(reference, source, cutoff=cutoff)
            assert list(dist.items()) == list(want_dist.items())
            assert {v: route_to(before, source, v) for v in dist} == want_paths
        for goal in range(0, edges.n, 5):
            want = None
            try:
                want = nx.astar_path(reference, source, goal, heuristic=lambda u, _v: heuristic[u])
            except nx.NetworkXNoPath:
                pass
            assert edges.astar(source, goal, lambda i: heuristic[i]) == want


def test_strong_components_of_an_edgeless_and_an_empty_graph():
    count_, labels = strong_components(3, [], [])
    assert count_ == 3 and sorted(labels.tolist()) == [0, 1, 2]
    assert strong_components(0, [], [])[0] == 0


def networkx_lane_graph(odr, lane_change_cost: float = 5.0) -> nx.DiGraph:
    """The lane graph as it was built before the arrays: a networkx graph from the map's links."""
    graph = nx.DiGraph()
    forward = {}
    for r, road in enumerate(odr.roads):
        for k, section in enumerate(road.lane_sections):
            for lane in section.side_lanes:
                if lane.type == "driving":
                    forward[LaneKey(r, k, lane.id)] = drives_with_s(road, lane)
    order = sorted(forward, key=lambda key: _row(odr, key))  # the map's row order
    for key in order:
        graph.add_node(key)
    exits = {(*key, "end" if ahead else "start"): key for key, ahead in forward.items()}
    entries = {(*key, "start" if ahead else "end"): key for key, ahead in forward.items()}
    reference = LaneGraph.from_opendrive(odr)
    for p, q in lane_end_pairs(odr):
        for a, b in ((p, q), (q, p)):
            if a in exits and b in entries and exits[a] != entries[b]:
                graph.add_edge(exits[a], entries[b], kind="follow", weight=reference.length(exits[a]))
    for key in order:
        ahead = forward[key]
        road = odr.roads[key.road_index]
        section = road.lane_sections[key.section_index]
        middle = 0.5 * (section.s0 + road.section_end(key.section_index))
        plus, minus = lane_toward_plus_t(key.lane_id), lane_toward_minus_t(key.lane_id)
        for kind, other in (("left", plus if ahead else minus), ("right", minus if ahead else plus)):
            neighbour = LaneKey(key.road_index, key.section_index, other)
            if forward.get(neighbour) is ahead and lane_change_allowed(section, key.lane_id, other, middle):
                graph.add_edge(key, neighbour, kind=kind, weight=float(lane_change_cost))
    return graph


def _row(odr, key: LaneKey) -> int:
    arrays = odr.arrays
    first = np.searchsorted(arrays.section_road, key.road_index, side="left")
    rows = np.flatnonzero((arrays.lane_section == first + key.section_index) & (arrays.lane_id == key.lane_id))
    return int(rows[0])


@pytest.mark.slow
def test_lane_graph_of_a_real_map_routes_as_networkx_did(tavf_xodr):
    odr = load_opendrive(tavf_xodr)
    graph = LaneGraph.from_opendrive(odr)
    reference = networkx_lane_graph(odr)
    assert graph.keys == list(reference.nodes)
    assert graph.edge_list() == list(reference.edges(data="kind"))
    assert all(graph.edge_weight(a, b) == w for a, b, w in reference.edges(data="weight"))
    assert {frozenset(c) for c in graph.strongly_connected_components()} == \
        {frozenset(c) for c in nx.strongly_connected_components(reference)}
    biggest = max(nx.strongly_connected_components(reference),
                  key=lambda c: (sum(graph.length(k) for k in c), len(c), min(c)))
    assert graph.largest_strongly_connected() == biggest
    keys = graph.keys
    sources = keys[:: max(1, len(keys) // 40)]
    for key in sources:
        assert graph.successors(key) == sorted(b for b in reference.successors(key)
                                               if reference.edges[key, b]["kind"] == "follow")
        assert graph.predecessors(key) == sorted(a for a in reference.predecessors(key)
                                                 if reference.edges[a, key]["kind"] == "follow")
        dist, paths = graph.routes_from(key, cutoff=3000.0)
        want_dist, want_paths = nx.single_source_dijkstra(reference, key, cutoff=3000.0, weight="weight")
        assert list(dist.items()) == list(want_dist.items()) and paths == want_paths
        assert graph.distances_from(key, 500.0) == nx.single_source_dijkstra_path_length(reference, key, cutoff=500.0)
    tied = 0
    for a, b in itertools.islice(itertools.product(sources, sources[::3]), 400):
        target = graph.start(b)
        try:
            want = nx.astar_path(reference, a, b, weight="weight",
                                 heuristic=lambda u, _v: math.dist(graph.start(u), target))
        except nx.NetworkXNoPath:
            want = None
        got = None
        try:
            got = graph.shortest_path(a, b)
        except Exception:  # noqa: BLE001 -- NoRouteError, compared below
            pass
        assert got == want, (a, b)
        if want is not None and len(list(itertools.islice(nx.all_shortest_paths(reference, a, b, weight="weight"),
                                                          2))) > 1:
            tied += 1
    assert tied > 0, "the check must include routes whose cost ties"


def test_a_locator_near_a_drive_locates_it_as_the_whole_maps_locator(tavf_xodr):
    """Metrics locate a drive's points through a tree over the samples around them only; the locations must be
    those of the whole map's tree, also for points far from every lane and for points far apart."""
    graph = LaneGraph.from_opendrive(load_opendrive(tavf_xodr))
    whole = graph.locator()
    data = whole.tree.data
    rng = np.random.default_rng(11)
    centre = data[len(data) // 3]
    around = data[np.hypot(*(data - centre).T) < 150.0]
    drive = around + rng.normal(0.0, 1.5, around.shape)  # on lanes within 150 m, noisy
    lonely = data.max(axis=0) + [400.0, 250.0]  # far outside the map: its nearest samples are far away
    far_apart = data[[10, len(data) - 10]]
    for points in (drive, np.vstack([drive[:50], lonely]), far_apart):
        near = graph.locator(near=(points[:, 0], points[:, 1]), candidates=16)
        a = near.locate(points[:, 0], points[:, 1], candidates=16)
        b = whole.locate(points[:, 0], points[:, 1], candidates=16)
        for field in ("road_index", "section_index", "lane_id", "s", "t", "distance"):
            np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    near = graph.locator(near=(drive[:, 0], drive[:, 1]), candidates=16)
    assert len(near.s) < 0.5 * len(whole.s), "a drive's neighbourhood, not the whole map"


def test_samples_of_some_lanes_are_those_of_the_whole_table(tavf_xodr):
    """The lane graph keeps no centre-line samples (a region's are 200 MB); those of some lanes, evaluated when
    asked, are exactly the whole table's samples of those lanes."""
    from tavf_mapkit.lanegraph.geometry import LaneTable

    odr = load_opendrive(tavf_xodr)
    graph = LaneGraph.from_opendrive(odr)
    driving = odr.arrays.lane_type == "driving"
    whole = LaneTable.build(odr, 1.0, keep=driving)
    row, s, xy = graph.samples()
    np.testing.assert_array_equal(row, whole.sample_row)
    np.testing.assert_array_equal(s, whole.sample_s)
    np.testing.assert_array_equal(xy, whole.sample_xy)
    some = np.zeros(len(driving), dtype=bool)
    some[np.flatnonzero(driving)[::7]] = True
    row, s, xy = graph.samples(some)
    picked = some[whole.sample_row]
    assert 0 < picked.sum() < len(picked)
    np.testing.assert_array_equal(row, whole.sample_row[picked])
    np.testing.assert_array_equal(s, whole.sample_s[picked])
    np.testing.assert_array_equal(xy, whole.sample_xy[picked])
    # each lane's box holds its samples
    box = graph._table.box[row]
    assert np.all((xy >= box[:, :2]) & (xy <= box[:, 2:]))


def test_a_graph_builds_its_lane_table_only_when_lengths_are_asked_for(tavf_xodr):
    """A drive's start needs the topology and the lanes' lines, not the lane table (on a region the largest part
    of the graph): from_opendrive and the random routes leave it unbuilt; built later, the lengths, ends and edge
    weights are those of a graph given the table at once."""
    from tavf_mapkit.lanegraph.geometry import LaneTable
    from twin.map.lanelines import LaneLines
    from twin.planning.random_routes import RandomRoutes

    odr = load_opendrive(tavf_xodr)
    lazy = LaneGraph.from_opendrive(odr)
    RandomRoutes(lazy, LaneLines(lazy))
    assert "_table" not in lazy.__dict__
    topology = lazy._topology
    assert np.all(np.isnan(topology.weight[topology.kind == 0]))  # follow edges: the lane they leave, later
    table = LaneTable.build(odr, 1.0, keep_samples=False)
    eager = LaneGraph(odr, lazy.keys, lazy._row, lazy._ahead, topology, table, 1.0, lazy.lane_types)
    assert lazy.edges.weight.tolist() == eager.edges.weight.tolist()
    follow = lazy.edges.kind == 0
    assert np.array_equal(lazy.edges.weight[follow], table.length[lazy._row[lazy.edges.source[follow]]])
    assert [lazy.length(k) for k in lazy.keys] == [eager.length(k) for k in eager.keys]
    assert [lazy.start(k) + lazy.end(k) for k in lazy.keys] == [eager.start(k) + eager.end(k) for k in eager.keys]
    some = lazy.keys[::max(len(lazy.keys) // 20, 1)]
    assert all(lazy.shortest_path(a, b) == eager.shortest_path(a, b) for a, b in itertools.pairwise(some)
               if eager.distances_from(a).get(b) is not None)
