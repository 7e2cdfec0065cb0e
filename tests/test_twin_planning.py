"""Lane waypoints, random routes that never dead-end, lane-change spans and recorded-route joining."""

from __future__ import annotations

import itertools

import networkx as nx
import numpy as np
import pytest

from tavf_mapkit.lanegraph import LaneGraph
from tavf_mapkit.opendrive import load_opendrive
from twin.map.lanelines import LaneLines
from twin.map.waypoints import Waypoint, WaypointMap
from twin.planning.chunks import route_spans
from twin.planning.random_routes import RandomRoutes
from twin.planning.recorded import Anchor, join_anchors
from twin.sim.build import Build


@pytest.fixture(scope="module")
def sample(sample_build_dir):
    odr = load_opendrive(Build.open(sample_build_dir).xodr)
    graph = LaneGraph.from_opendrive(odr)
    return odr, graph, LaneLines(graph)


def test_random_walk_stays_in_a_closed_component_and_never_dead_ends(sample):
    _, graph, lines = sample
    routes = RandomRoutes(graph, lines)
    lanes = routes.lanes
    sub = graph.to_networkx().subgraph(lanes)
    assert nx.is_strongly_connected(sub)
    walk = list(itertools.islice(routes.walk(np.random.default_rng(5)), 3000))
    assert set(walk) <= lanes
    for a, b in itertools.pairwise(walk):
        assert graph.has_edge(a, b)
    # lane changes happen but never straight back and forth
    kinds = [graph.edge_kind(a, b) for a, b in itertools.pairwise(walk)]
    assert "follow" in kinds and ({"left", "right"} & set(kinds))
    for (a, b), (c, d) in itertools.pairwise(itertools.pairwise(walk)):
        if graph.edge_kind(a, b) != "follow" and graph.edge_kind(c, d) != "follow":
            assert d != a or len(routes._lateral[c]) == 1


def test_random_walk_is_seeded(sample):
    _, graph, lines = sample
    routes = RandomRoutes(graph, lines)
    first = list(itertools.islice(routes.walk(np.random.default_rng(1)), 200))
    again = list(itertools.islice(routes.walk(np.random.default_rng(1)), 200))
    other = list(itertools.islice(routes.walk(np.random.default_rng(2)), 200))
    assert first == again and first != other


def test_waypoints_branch_at_junctions(sample):
    _, graph, lines = sample
    waypoints = WaypointMap(graph)
    branching = next(k for k in sorted(graph.keys) if len(graph.successors(k)) >= 2)
    length = lines[branching].length
    ahead = waypoints.next(Waypoint(branching, length - 1.0), 3.0)
    assert sorted(w.key for w in ahead) == graph.successors(branching)
    assert all(w.along == pytest.approx(2.0) for w in ahead)
    inside = waypoints.next(Waypoint(branching, 0.0), min(1.0, length / 2))
    assert len(inside) == 1 and inside[0].key == branching
    pose = waypoints.pose(Waypoint(branching, 0.0))
    assert (pose.x, pose.y) == pytest.approx(tuple(lines[branching].points[0, :2]))
    assert waypoints.lane_change(Waypoint(branching, 0.0)) in ("None", "Left", "Right", "Both")
    assert len(waypoints.generate(10.0)) >= len(graph)


def test_lane_change_run_splits_the_section(sample):
    _, graph, lines = sample
    change = next((a, b) for a, b, kind in sorted(graph.edge_list()) if kind == "left")
    after = graph.successors(change[1])
    route = [change[0], change[1], *after[:1]]
    spans = list(route_spans(lines, graph, route))
    assert [s.key for s in spans] == route
    assert spans[0].start == 0.0 and spans[0].stop < spans[1].start  # the diagonal lies between them
    assert spans[1].stop is None and spans[-1].start == 0.0


def test_join_anchors_skips_what_only_a_detour_reaches(sample):
    _, graph, lines = sample
    routes = RandomRoutes(graph, lines)
    walk = list(itertools.islice(routes.walk(np.random.default_rng(3)), 12))
    # a recording that drove the walk, five fixes per lane, one of them matched to a far-away lane
    anchors, driven = [], 0.0
    for k, key in enumerate(walk):
        length = lines[key].length
        if k and graph.edge_kind(walk[k - 1], key) == "follow":
            driven += lines[walk[k - 1]].length
        anchors.append(Anchor(key, 5, 0.0, length, driven, driven + length))
    end = np.asarray(graph.end(walk[5]))
    stray = max((k for k in graph.keys if k not in walk),
                key=lambda k: float(np.linalg.norm(np.asarray(graph.start(k)) - end)))
    a = anchors[5]
    anchors.insert(6, Anchor(stray, 1, 1.0, 1.0, a.trace_last + 1.0, a.trace_last + 1.0))
    route, placed = join_anchors(graph, anchors)
    assert placed[6] == -1 and stray not in route
    assert route == walk
    assert [p for p in placed if p >= 0] == sorted(p for p in placed if p >= 0)
