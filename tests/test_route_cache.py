"""Random-route plans kept between drives (twin.planning.route_cache): read back, the routes walk exactly as
computed ones, a drive from a plan is the same drive, and it builds only the lines of lanes the car reaches."""

from __future__ import annotations

import os

import numpy as np
import pytest

from tavf_mapkit.lanegraph import LaneGraph
from tavf_mapkit.opendrive.snapshot import load_build_map
from twin.map.lanelines import LaneLines
from twin.planning import route_cache
from twin.planning.chunks import LaneCodes
from twin.planning.random_routes import RandomRoutes
from twin.session.config import DriveConfig
from twin.session.loop import Session
from twin.sim.build import Build


def _routes(build_dir, cached: bool):
    build = Build.open(build_dir)
    graph = LaneGraph.from_opendrive(load_build_map(build.xodr))
    lines = LaneLines(graph)
    routes = RandomRoutes.cached(graph, lines, build.xodr, build.map_sha256) if cached else \
        RandomRoutes(graph, lines)
    return routes, lines


def _walk(routes, seed: int, count: int = 400) -> list:
    rng = np.random.default_rng(seed)
    walk = routes.walk(rng)
    return [next(walk) for _ in range(count)]


def test_a_plan_read_back_walks_as_the_computed_routes(sample_build_dir, tmp_path, monkeypatch):
    monkeypatch.setenv("MAPKIT_CACHE", str(tmp_path))
    computed, _ = _routes(sample_build_dir, cached=False)
    first, _ = _routes(sample_build_dir, cached=True)  # computes and saves the plan
    assert first.transitions is not None and len(list((tmp_path / "routes").glob("*.npz"))) == 1
    again, lines = _routes(sample_build_dir, cached=True)  # reads it back
    assert again.transitions is None and again.undrivable is None
    assert lines._ends.index == {}  # no line measured: the map's lines were not evaluated
    for name in ("mode", "lanes", "_sorted", "_follow", "_lateral", "_turnaround", "_towards"):
        assert getattr(again, name) == getattr(computed, name), name
    assert [again.lines.length(k) for k in again._sorted] == [computed.lines.length(k) for k in computed._sorted]
    for seed in range(3):
        assert _walk(again, seed) == _walk(computed, seed)
    build = Build.open(sample_build_dir)
    kept = route_cache.kept_lane_graph(again.graph.odr, build.xodr, build.map_sha256)
    graph = again.graph
    assert kept.keys == graph.keys and kept.edge_list() == graph.edge_list()
    assert np.array_equal(kept._row, graph._row) and np.array_equal(kept._ahead, graph._ahead)
    assert kept.edges.weight.tolist() == graph.edges.weight.tolist()  # lengths from the lane table, as ever
    codes = LaneCodes(again.graph)
    chunks_again = again.chunks(codes, np.random.default_rng(5))
    chunks_computed = computed.chunks(LaneCodes(computed.graph), np.random.default_rng(5))
    for _ in range(60):
        a, b = next(chunks_again), next(chunks_computed)
        assert np.array_equal(a.points, b.points) and np.array_equal(a.lane_code, b.lane_code)
        assert np.array_equal(a.speed_limit, b.speed_limit) and a.begins == b.begins


def test_a_plan_is_refused_for_another_lane_graph_or_map_file(sample_build_dir, tmp_path, monkeypatch):
    monkeypatch.setenv("MAPKIT_CACHE", str(tmp_path))
    routes, _ = _routes(sample_build_dir, cached=True)
    (plan_file,) = (tmp_path / "routes").glob("*.npz")
    plan = route_cache.load_plan(plan_file, routes.graph)
    assert plan is not None
    other = LaneGraph.from_opendrive(routes.graph.odr, lane_types=("driving", "biking"))
    if other.keys != routes.graph.keys:
        assert route_cache.load_plan(plan_file, other) is None
    plan_file.write_bytes(b"not a plan")
    assert route_cache.load_plan(plan_file, routes.graph) is None  # damaged: computed again, never an error
    build = Build.open(sample_build_dir)
    stat = build.xodr.stat()
    key = route_cache.plan_key(build.xodr, build.map_sha256, {"a": 1})
    os.utime(build.xodr, ns=(stat.st_atime_ns, stat.st_mtime_ns + 1))
    try:
        assert route_cache.plan_key(build.xodr, build.map_sha256, {"a": 1}) != key  # the file changed
    finally:
        os.utime(build.xodr, ns=(stat.st_atime_ns, stat.st_mtime_ns))
    monkeypatch.setenv("MAPKIT_CACHE", "off")
    assert route_cache.cache_folder() is None


@pytest.mark.parametrize("vehicles", [1, 3])
def test_a_drive_from_a_plan_is_the_computed_drive_and_builds_only_the_lines_it_reaches(
        sample_build_dir, tmp_path, monkeypatch, vehicles):
    def drive(name: str, cache: str):
        monkeypatch.setenv("MAPKIT_CACHE", cache)
        config = DriveConfig(map=sample_build_dir, out=tmp_path / name, random=True, duration=30.0, seed=3,
                             vehicles=vehicles, plot=False)
        session = Session(config, [])
        session.run()
        return session, (tmp_path / name / "trajectory.csv").read_bytes()

    _, computed = drive("off", "off")
    first_session, first = drive("first", str(tmp_path / "cache"))
    session, again = drive("again", str(tmp_path / "cache"))
    assert first == computed and again == computed
    assert first_session.random_routes.transitions is not None and session.random_routes.transitions is None
    built = set(session.lines._cache)
    assert session.lines._ends.index == {} and built  # lines built as the cars reached their lanes only
    assert built <= set(session.random_routes.lanes)


def test_the_plans_code_digest_covers_route_planning_and_the_map_model_not_the_file_reader(monkeypatch):
    import tavf_mapkit

    root = __import__("pathlib").Path(tavf_mapkit.__file__).parent.parent
    read = []
    original = type(root).read_bytes
    monkeypatch.setattr(type(root), "read_bytes", lambda self: read.append(self.relative_to(root).as_posix())
                        or original(self))
    route_cache.code_digest.cache_clear()
    try:
        route_cache.code_digest()
    finally:
        route_cache.code_digest.cache_clear()
    for needed in ("twin/planning/drivable.py", "twin/map/lanelines.py", "tavf_mapkit/lanegraph/graph.py",
                   "tavf_mapkit/opendrive/arrays.py", "tavf_mapkit/opendrive/lane.py", "tavf_mapkit/mesh/exact.py"):
        assert needed in read
    assert "tavf_mapkit/opendrive/reader.py" not in read and "tavf_mapkit/pipeline/stages.py" not in read
