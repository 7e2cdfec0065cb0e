"""Random routes always make progress: no lane-change-only loops, bounded-time failure instead of a hang,
turnarounds and restarts on networks without a closed loop, centre lines without netconvert's folds."""

from __future__ import annotations

import itertools
import json
import math

import numpy as np
import pytest
from click.testing import CliRunner
from conftest import _build, shared_path

from tavf_mapkit.errors import InputError
from tavf_mapkit.lanegraph import LaneGraph, LaneKey
from tavf_mapkit.opendrive import load_opendrive, loads_opendrive
from twin.cli.main import cli
import twin.map.lanelines as lanelines_module
from twin.map.lanelines import LaneLines, without_folds, without_loops
from twin.planning.buffer import PathBuffer
from twin.planning.chunks import (RESTART, TURNAROUND, LaneCodes, RouteBreak, RouteStalled, expand_route,
                                  route_spans)
from twin.planning.drivable import MAX_CUT, corner_cut, min_turn_radius, total_turning, undrivable_lanes, \
    worst_cuts
from twin.planning.random_routes import RandomRoutes
from twin.sim.build import Build


def _lane(lane_id, width=3.5, link="", mark="broken"):
    return (f'<lane id="{lane_id}" type="driving"><link>{link}</link>'
            f'<width sOffset="0" a="{width}" b="0" c="0" d="0"/><roadMark sOffset="0" type="{mark}"/></lane>')


def _straight_road(length, left=(), right=(), road_id="1"):
    left_xml = f"<left>{''.join(left)}</left>" if left else ""
    right_xml = f"<right>{''.join(right)}</right>" if right else ""
    return (f'<road id="{road_id}" length="{length}" junction="-1"><link/>'
            f'<planView><geometry s="0" x="0" y="0" hdg="0" length="{length}"><line/></geometry></planView>'
            f'<lanes><laneSection s="0">{left_xml}<center><lane id="0" type="none"/></center>{right_xml}'
            f'</laneSection></lanes></road>')


def _graph(*roads):
    odr = loads_opendrive('<?xml version="1.0"?><OpenDRIVE><header revMajor="1" revMinor="6"/>'
                          f'{"".join(roads)}</OpenDRIVE>')
    graph = LaneGraph.from_opendrive(odr)
    return graph, LaneLines(graph)


def _items(routes, count, seed=0):
    return list(itertools.islice(routes.walk(np.random.default_rng(seed)), count))


def test_a_lane_change_cycle_is_no_loop_and_a_route_stuck_in_one_raises():
    # one one-way road with two lanes and a broken line between them: the lane graph's only cycle is
    # -1 -> -2 -> -1, two lane changes; the walk used to alternate between them for ever
    graph, lines = _graph(_straight_road(100.0, right=[_lane(-1), _lane(-2)]))
    a, b = LaneKey(0, 0, -1), LaneKey(0, 0, -2)
    assert graph.edge_kind(a, b) != "follow" and graph.edge_kind(b, a) != "follow"
    routes = RandomRoutes(graph, lines)
    assert routes.mode == "restart"  # no closed loop, no lane of the opposite direction to turn into
    items = _items(routes, 200)
    assert items[1::2] == [RESTART] * 100 and set(items[::2]) == {a, b}  # one lane, then a new route
    chunks = list(itertools.islice(routes.chunks(LaneCodes(graph), np.random.default_rng(0)), 50))
    assert all(len(c) == 101 for c in chunks)  # every part drives the whole road
    assert [c.begins for c in chunks] == [None] + ["restart"] * 49
    # a route that only changes lanes fails at once instead of splitting one section for ever
    with pytest.raises(RouteStalled, match="changes lanes in a circle on road 1"):
        list(route_spans(lines, graph, itertools.islice(itertools.cycle([a, b]), 10_000)))


def test_a_route_over_lanes_without_length_raises():
    graph, lines = _graph(_straight_road(0.5, right=[_lane(-1)]),
                          _straight_road(50.0, right=[_lane(-1)], road_id="2"))
    tiny = LaneKey(0, 0, -1)
    with pytest.raises(RouteStalled, match="without covering a metre"):
        list(expand_route(lines, LaneCodes(graph), itertools.islice(itertools.repeat(tiny), 5000)))


def test_a_network_of_sub_metre_lanes_is_refused_in_one_line():
    graph, lines = _graph(_straight_road(0.5, right=[_lane(-1)]))
    with pytest.raises(InputError, match="no drivable lane of 1 m or more"):
        RandomRoutes(graph, lines)


def test_a_single_two_way_street_turns_around_at_both_ends():
    graph, lines = _graph(_straight_road(200.0, left=[_lane(1)], right=[_lane(-1)]))
    east, west = LaneKey(0, 0, -1), LaneKey(0, 0, 1)
    routes = RandomRoutes(graph, lines)
    assert routes.mode == "turnaround" and routes.lanes == {east, west}
    items = _items(routes, 9, seed=3)
    lanes = [i for i in items if isinstance(i, LaneKey)]
    assert all(isinstance(i, RouteBreak) for i in items[1::2]) and set(items[1::2]) == {TURNAROUND}
    assert all(p != q for p, q in itertools.pairwise(lanes))  # east, west, east, ...
    # the path buffer stops the car at the street's end and holds the opposite lane until the turnaround
    buffer = PathBuffer(1, horizon=300.0)
    buffer.assign(0, routes.chunks(LaneCodes(graph), np.random.default_rng(3), start=east))
    n = int(buffer.count[0])
    assert buffer.waiting[0] and buffer.x[0, n - 1] == pytest.approx(200.0) and buffer.vmax[0, n - 1] == 0.0
    assert buffer.remaining(0) == pytest.approx(200.0)  # nothing of the way back is part of this path
    assert not buffer.at_break(np.array([150.0]), 2.0)[0] and buffer.at_break(np.array([198.5]), 2.0)[0]
    assert buffer.jump(0) == "turnaround"
    assert (buffer.x[0, 0], buffer.y[0, 0]) == pytest.approx((200.0, 1.75))  # the westbound lane's start
    assert buffer.x[0, 1] < buffer.x[0, 0] and buffer.waiting[0]


def test_a_one_way_dead_end_restarts():
    graph, lines = _graph(_straight_road(80.0, right=[_lane(-1)]),
                          _straight_road(60.0, right=[_lane(-1)], road_id="2"))
    routes = RandomRoutes(graph, lines)
    assert routes.mode == "restart"
    items = _items(routes, 400, seed=1)
    assert set(items[1::2]) == {RESTART} and set(items[::2]) == {LaneKey(0, 0, -1), LaneKey(1, 0, -1)}


def _road(road_id, x, y, hdg, length, link="", lane_link=""):
    return (f'<road id="{road_id}" length="{length}" junction="-1"><link>{link}</link>'
            f'<planView><geometry s="0" x="{x}" y="{y}" hdg="{hdg}" length="{length}"><line/></geometry>'
            '</planView>'
            f'<lanes><laneSection s="0"><center><lane id="0" type="none"/></center>'
            f'<right>{_lane(-1, link=lane_link)}</right></laneSection></lanes></road>')


def test_a_lane_leading_only_into_a_bend_no_car_can_take_is_never_driven():
    """Taipei: a left turn netconvert splits over two junctions, the second turning a right angle on the spot.
    The step is rightly not driven, but the walk (restart mode: one-way roads leaving the map) still entered
    the lane before it, stopped in the middle of the junction and restarted there. A dead end of our making is
    no dead end of the map: such lanes are left out, so restarts happen where the map ends."""
    graph, lines = _graph(
        _road("1", 0, 0, 0, 80, link='<successor elementType="road" elementId="2" contactPoint="start"/>',
              lane_link='<successor id="-1"/>'),
        _road("2", 78.25, -1.75, math.pi / 2, 60,
              link='<predecessor elementType="road" elementId="1" contactPoint="end"/>',
              lane_link='<predecessor id="-1"/>'),
        _road("3", 0, 50, 0, 70))
    first, second, other = LaneKey(0, 0, -1), LaneKey(1, 0, -1), LaneKey(2, 0, -1)
    assert graph.successors(first) == [second]
    routes = RandomRoutes(graph, lines)
    assert routes.transitions.dropped[first, second].startswith("cuts a bend")
    assert first in routes.transitions.blocked
    assert routes.mode == "restart" and routes.lanes == {second, other}
    items = _items(routes, 400, seed=2)
    assert first not in items and set(items[1::2]) == {RESTART}


def test_closed_loops_are_preferred_and_never_need_a_break(sample_build_dir):
    graph = LaneGraph.from_opendrive(load_opendrive(Build.open(sample_build_dir).xodr))
    routes = RandomRoutes(graph, LaneLines(graph))
    assert routes.mode == "loop"
    assert not any(isinstance(i, RouteBreak) for i in _items(routes, 3000))
    # the sample's dead ends have netconvert turnarounds: U-turn lanes, which a car does not drive in lane
    assert "u-turn" in routes.undrivable.values()


def test_folds_of_an_offset_centre_line_are_cut_out():
    # a straight line with a swallowtail: forward to x=10, a loop back to x=8, on again
    loop = np.array([[0, 0, 0], [5, 0, 0], [10, 0, 0], [10.5, 0.5, 0], [9.5, 1.0, 0], [8.0, 0.3, 0],
                     [9, -0.2, 0], [12, -0.2, 0], [20, -0.2, 0]], dtype=float)
    cut = without_loops(loop)
    assert len(cut) < len(loop) and np.all(np.diff(cut[:, 0]) > 0)  # only forward steps are left
    # a zig-zag that doubles back without crossing (the fold of a lane cut by the lane's end)
    folded = np.array([[0, 0, 0], [-0.5, 0.1, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0], [10, 0, 0]], dtype=float)
    assert np.all(np.diff(without_folds(folded)[:, 0]) > 0) and without_folds(folded)[-1, 0] == 10.0
    # a real bend (a quarter circle of 10 m radius) is left alone
    angle = np.linspace(0, math.pi / 2, 20)
    arc = np.column_stack([10 * np.sin(angle), 10 - 10 * np.cos(angle), np.zeros(20)])
    assert np.array_equal(without_folds(without_loops(arc)), arc)


@pytest.fixture(scope="module")
def berlin_build(tmp_path_factory):
    return _build(tmp_path_factory, "berlin", shared_path("osm_small", "berlin-siegessaeule.osm.gz"))


@pytest.fixture(scope="module")
def krautsand_build(tmp_path_factory):
    return _build(tmp_path_factory, "krautsand", shared_path("osm_small", "krautsand.osm.gz"))


def test_junction_lanes_of_berlin_stay_drivable(berlin_build):
    """On the Grosser Stern build the old per-vertex bend test dropped 25 lanes with "radii" of 0.2-7.5 m
    (mostly folds of outer lanes on tight reference lines), and the largest part left was three lanes
    joined only by lane changes. On centre lines without folds no lane and no step between lanes makes the
    car cut a bend by a metre, and the walk has the whole roundabout."""
    graph = LaneGraph.from_opendrive(load_opendrive(Build.open(berlin_build).xodr))
    lines = LaneLines(graph)
    routes = RandomRoutes(graph, lines)
    assert routes.undrivable == {} and routes.transitions.dropped == {}
    assert routes.mode == "loop" and len(routes.lanes) >= 70


def test_bends_are_measured_by_how_far_the_car_cuts_them():
    radius = min_turn_radius()
    assert radius == pytest.approx(2.96 / math.tan(math.radians(35.0) * 0.8))  # 5.6 m at the steering limit
    lane = np.zeros(41, dtype=np.int64)
    straight = np.column_stack([np.linspace(-20, 20, 41), np.zeros(41)])
    assert corner_cut(lane, straight, radius).max() == 0.0

    def corner(angle):  # two straight legs of 20 m meeting at a kink that turns by ``angle``
        legs = np.linspace(0.0, 20.0, 21)
        after = np.column_stack([legs * math.cos(angle), legs * math.sin(angle)])[1:]
        return np.concatenate([np.column_stack([legs - 20.0, np.zeros(21)]), after])

    def arc(r, angle):
        t = np.linspace(0.0, angle, max(int(r * angle), 2) + 1)
        return np.column_stack([r * np.sin(t), r - r * np.cos(t)])

    kink = corner(math.radians(20)).shape[0]
    small = corner_cut(np.zeros(kink, dtype=np.int64), corner(math.radians(20)), radius).max()
    right = corner_cut(np.zeros(kink, dtype=np.int64), corner(math.radians(90)), radius).max()
    exact = radius * (1 / math.cos(math.radians(45)) - 1)  # 2.3 m: the car's arc inside a right angle
    assert small < 0.2 and 0.7 * exact < right <= exact
    wide = arc(8.0, math.pi / 2)  # a junction turn of 8 m radius: the car follows it
    assert corner_cut(np.zeros(len(wide), dtype=np.int64), wide, radius).max() == 0.0


def test_bulk_centre_lines_are_the_one_by_one_centre_lines(sample_build_dir):
    graph = LaneGraph.from_opendrive(load_opendrive(Build.open(sample_build_dir).xodr))
    keys = sorted(graph.keys)
    bulk = graph.centerlines(keys)
    for key in keys:
        points, s = graph.centerline(key)
        # the same samples; paramPoly3 arc-length inversion converges per batch, so within a micrometre
        assert np.array_equal(bulk[key][1], s) and np.allclose(bulk[key][0], points, rtol=0, atol=1e-6)


@pytest.mark.slow
def test_krautsand_drives_ten_minutes_turning_around_at_its_dead_ends(krautsand_build, tmp_path):
    """The rural Krautsand extract has no closed loop once netconvert's turnarounds are left out: the twin
    used to refuse it. Now it drives, turns around at the dead ends, and ends by itself, reproducibly."""
    runs = []
    for name in ("a", "b"):
        result = CliRunner().invoke(cli, ["drive", "--map", str(krautsand_build), "--random", "--duration",
                                          "600", "--seed", "0", "-o", str(tmp_path / name), "--no-record",
                                          "--no-plot", "--json"])
        assert result.exit_code == 0, result.output
        runs.append(json.loads(result.output))
    metrics = runs[0]
    assert metrics["route_mode"] == "turnaround" and metrics["turnarounds"] >= 1 and metrics["restarts"] == 0
    assert metrics["resets"] == 0 and metrics["collisions"] == 0 and metrics["off_road_seconds"] == 0.0
    assert metrics["distance_m"] > 5000 and metrics["sim_seconds"] == 600.0
    trajectories = [(tmp_path / name / "trajectory.csv").read_bytes() for name in ("a", "b")]
    assert trajectories[0] == trajectories[1]


def _lines_one_by_one(graph, keys):
    """The lane lines as LaneLines built them before its batch shortcuts: every line through both filters,
    arc length by a cumsum of the line alone."""
    found = {}
    for key, (points, _) in graph.centerlines(keys).items():
        points = without_folds(without_loops(points))
        along = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points[:, :2], axis=0), axis=1))])
        found[key] = (points, along)
    return found


def test_batched_lane_lines_are_the_one_by_one_lines_to_the_bit(berlin_build):
    """LaneLines runs the loop and fold filters only on lines that may have one and sums arc lengths for
    all lines at once; every line must still be the one the filters give, bit for bit (routes and
    trajectories depend on it). Berlin's Grosser Stern has folded outer lanes, so both paths are taken."""
    graph = LaneGraph.from_opendrive(load_opendrive(Build.open(berlin_build).xodr))
    keys = sorted(graph.keys)
    lines = LaneLines(graph)
    lines.preload(keys)
    expected = _lines_one_by_one(graph, keys)
    raw = graph.centerlines(keys)
    changed = [k for k in keys if len(raw[k][0]) != len(expected[k][0])]
    assert changed, "no folded line on this map: the filter path is not exercised"
    for key in keys:
        points, along = expected[key]
        assert np.array_equal(lines[key].points, points) and np.array_equal(lines[key].along, along), key


def test_bends_too_gentle_to_matter_are_not_measured_but_decide_the_same():
    """worst_cuts measures only lines whose total turning (as corner_cut sees them: without points closer than
    JOIN_GAP to the one before) could make the car cut by more than the limit; its decisions are those of
    measuring every line, its measured values exact, its bounds never below the true cut."""
    from twin.planning.drivable import _distinct

    rng = np.random.default_rng(7)
    radius = min_turn_radius()
    lines = []
    for i in range(300):
        n = int(rng.integers(2, 60))
        step = rng.uniform(0.05, 2.0, n)
        # gentle wiggles, arcs, kinks and hairpins, some with repeated points and near-repeats
        turn = rng.normal(0.0, [0.002, 0.05, 0.3, 1.5][i % 4], n)
        heading = np.cumsum(turn)
        xy = np.cumsum(np.column_stack([step * np.cos(heading), step * np.sin(heading)]), axis=0)
        if i % 7 == 0:
            xy = np.repeat(xy, 2, axis=0)
        lines.append(xy)
    lane = np.repeat(np.arange(len(lines)), [len(p) for p in lines])
    points = np.concatenate(lines)
    every = np.zeros(len(lines))
    np.maximum.at(every, lane, corner_cut(lane, points, radius))
    for limit in (0.05, MAX_CUT, 2.0):
        worst = worst_cuts(lane, points, radius, limit)
        assert np.array_equal(worst > limit, every > limit)
        assert np.all(worst >= every - 1e-12)
        distinct = _distinct(lane, points)  # corner_cut's thinned lines: repeated points turn nothing
        turning = np.minimum(total_turning(lane[distinct], points[distinct]), 0.9 * np.pi)
        assert np.all(turning <= np.minimum(total_turning(lane, points), 0.9 * np.pi) + 1e-12)
        measured = radius * (1 / np.cos(0.5 * turning) - 1) > 0.999 * limit
        assert 0 < measured.sum() < len(lines)  # both paths taken
        assert np.allclose(worst[measured], every[measured], rtol=0, atol=1e-12)


def test_lane_lines_and_bends_of_a_region_in_small_batches_are_the_same(berlin_build, monkeypatch):
    """A region's lane lines and steps are evaluated and measured BATCH_POINTS points at a time (all at once,
    Columbus's 7 million points took GBs); in batches of about 500 points Berlin's lines, dropped lanes and
    steps are those of one batch, to the bit."""
    import twin.map.lanelines as lanelines
    from twin.planning.drivable import lane_transitions

    graph = LaneGraph.from_opendrive(load_opendrive(Build.open(berlin_build).xodr))
    keys = sorted(graph.keys)
    whole = LaneLines(graph)
    whole.preload(keys)
    assert sum(len(whole[k].points) for k in keys) < lanelines.BATCH_POINTS  # one batch
    undrivable = undrivable_lanes(graph, whole)
    strict = undrivable_lanes(graph, whole, max_cut=0.05)  # bends measured and dropped, not only bounded
    steps = lane_transitions(graph, whole, undrivable)
    strict_steps = lane_transitions(graph, whole, undrivable, max_cut=0.05)
    monkeypatch.setattr(lanelines, "BATCH_POINTS", 500)
    assert len(list(lanelines.lane_batches(graph, keys, 1.0))) > 10
    batched = LaneLines(graph)
    assert undrivable_lanes(graph, batched) == undrivable
    assert undrivable_lanes(graph, batched, max_cut=0.05) == strict and len(strict) > len(undrivable)
    for key in keys:
        assert np.array_equal(batched[key].points, whole[key].points), key
        assert np.array_equal(batched[key].along, whole[key].along), key
    assert lane_transitions(graph, batched, undrivable) == steps
    assert lane_transitions(graph, batched, undrivable, max_cut=0.05) == strict_steps and strict_steps.dropped


def _without_loops_one_line(points, window=40):
    """The loop cut of one line as LaneLines made it line by line (the reference for the batched one)."""
    m = len(points) - 1
    if m < 3:
        return points
    a, d = points[:-1, :2], np.diff(points[:, :2], axis=0)
    heading = np.arctan2(d[:, 1], d[:, 0])
    if np.sum(np.abs((np.diff(heading) + np.pi) % (2 * np.pi) - np.pi)) < np.pi:
        return points
    hits = []
    for gap in range(2, min(window, m - 1) + 1):
        for i in range(m - gap):
            j = i + gap
            denominator = d[i, 0] * d[j, 1] - d[i, 1] * d[j, 0]
            if not abs(denominator) > 1e-12:
                continue
            r = a[j] - a[i]
            f = (r[0] * d[j, 1] - r[1] * d[j, 0]) / denominator
            g = (r[0] * d[i, 1] - r[1] * d[i, 0]) / denominator
            if 0 <= f <= 1 and 0 <= g <= 1:
                hits.append((i, j, f))
    pieces, done = [], 0
    for first in sorted({h[0] for h in hits}):
        if first < done:
            continue
        _, j, f = max((h for h in hits if h[0] == first), key=lambda h: h[1])
        pieces.append(points[done:first + 1])
        pieces.append((points[first] + f * (points[first + 1] - points[first]))[None, :])
        done = j + 1
    pieces.append(points[done:])
    return np.concatenate(pieces)


def test_loops_of_many_lines_cut_at_once_are_each_lines_own_cuts():
    """LaneLines cuts the loops of a region's folded lines in one pass per segment gap; every line comes out
    as cut on its own: loops, nested loops, figure eights, lines too short or turning too little to cross."""
    from twin.map.lanelines import lines_without_loops

    rng = np.random.default_rng(11)
    lines = []
    for k in range(400):
        n = int(rng.integers(2, 70))
        turn = rng.normal(0.0, [0.05, 0.4, 1.2, 2.5][k % 4], n)
        heading = np.cumsum(turn)
        step = rng.uniform(0.2, 2.0, n)
        xy = np.cumsum(np.column_stack([step * np.cos(heading), step * np.sin(heading)]), axis=0)
        lines.append(np.column_stack([xy, rng.uniform(0, 1, n)]))
    batched = lines_without_loops(lines)
    changed = 0
    for line, cut in zip(lines, batched):
        expected = _without_loops_one_line(line)
        assert np.array_equal(cut, expected)
        changed += len(expected) != len(line)
    assert changed > 20


def _lines_kept(lines):
    return len(lines._cache)


def test_route_selection_keeps_lane_ends_only_and_decides_as_on_whole_lines(berlin_build):
    """A region's route selection measures every lane's line once, batch by batch, and keeps only each lane's
    length and first and last metres (Columbus: 161,781 lines held ~300 MB beside the map). Its lanes, steps,
    turnarounds and walks are those of whole lines, and the ends are the whole lines' points, to the bit."""
    graph = LaneGraph.from_opendrive(load_opendrive(Build.open(berlin_build).xodr))
    keys = sorted(graph.keys)
    whole = LaneLines(graph)
    whole.preload(keys)
    expected = RandomRoutes(graph, whole)
    lines = LaneLines(graph)
    routes = RandomRoutes(graph, lines)
    assert _lines_kept(lines) == 0
    assert routes.undrivable == expected.undrivable and routes.transitions == expected.transitions
    assert (routes.mode, routes.lanes, routes._follow, routes._lateral, routes._turnaround, routes._towards) == \
        (expected.mode, expected.lanes, expected._follow, expected._lateral, expected._turnaround, expected._towards)
    assert _items(routes, 500, seed=3) == _items(expected, 500, seed=3)
    truncated = 0
    for key in keys:
        ends, line = lines.ends(key), whole[key]
        n, h, t = len(line.along), len(ends.head), len(ends.tail)
        assert ends.length == line.length and min(h, t) >= min(n, 2)
        assert np.array_equal(ends.head, line.points[:h, :2]) and np.array_equal(ends.head_along, line.along[:h])
        assert np.array_equal(ends.tail, line.points[n - t:, :2]) and np.array_equal(ends.tail_along, line.along[n - t:])
        assert h == n or line.along[h] > lanelines_module.ENDS_HEAD
        assert t == n or line.along[n - t] <= line.length - lanelines_module.ENDS_TAIL < line.along[n - t + 1]
        truncated += t < n
    assert truncated > len(keys) // 4


def test_a_join_blended_from_beyond_a_lanes_kept_end_reads_the_whole_line(monkeypatch):
    """A lane that starts metres beside the end of the one before is joined by a blend that replaces up to 20 m
    of that lane, more than its kept end: the step is measured on the whole line, as when all were kept."""
    from twin.planning.drivable import REACH, _step_polyline

    def roads(aside):
        return (_road("1", 0, 0, 0, 100, link='<successor elementType="road" elementId="2" contactPoint="start"/>',
                      lane_link='<successor id="-1"/>'),
                _road("2", 100, -aside, 0.1, 100,
                      link='<predecessor elementType="road" elementId="1" contactPoint="end"/>',
                      lane_link='<predecessor id="-1"/>'))

    read = []
    whole_line = LaneLines.line
    monkeypatch.setattr(LaneLines, "line", lambda self, key: read.append(key) or whole_line(self, key))
    a, b = LaneKey(0, 0, -1), LaneKey(1, 0, -1)
    for aside, reads in ((0.0, 0), (1.0, 0), (3.0, 1)):  # blends of 0 m, 8 m (inside the kept end), 20 m
        graph, lines = _graph(*roads(aside))
        assert graph.successors(a) == [b]
        whole = LaneLines(graph)
        whole.preload(graph.keys)
        list(lines.scan(graph.keys))
        read.clear()
        step = _step_polyline(lines, a, b)
        assert len(read) == reads and _lines_kept(lines) == 0
        assert np.array_equal(step, _step_polyline(whole, a, b))
        assert len(lines.ends(a).tail) < len(whole[a].points) and lines.ends(a).length > 4 * REACH


def test_steps_whose_lanes_meet_are_made_at_once_as_one_by_one(berlin_build):
    """Route selection makes the polylines of the steps whose lanes meet all at once from the lanes' kept ends
    (``twin.planning.steps``; Maribor has 29,364 steps): each is ``_step_polyline``'s, to the bit, and the
    heading of every lane's first and last segment is ``_headings``'."""
    from twin.planning import steps
    from twin.planning.drivable import _headings, _step_polyline

    graph = LaneGraph.from_opendrive(load_opendrive(Build.open(berlin_build).xodr))
    lines = LaneLines(graph)
    undrivable = undrivable_lanes(graph, lines)  # scans every lane: the ends table holds them all
    ends = lines.ends_arrays()
    pairs = sorted({(a, b) for a in graph.keys for b in graph.successors(a)})
    a = np.array([ends.index[p] for p, _ in pairs])
    b = np.array([ends.index[q] for _, q in pairs])
    joined, owner, points = steps.joined_steps(ends, a, b)
    assert 0 < joined.sum() <= len(pairs) and np.all(np.diff(owner) >= 0)
    made = {int(k): points[owner == k] for k in np.unique(owner)}
    assert sorted(made) == np.flatnonzero(joined).tolist()
    for k, step in made.items():
        assert np.array_equal(step, _step_polyline(lines, *pairs[k])), pairs[k]
    first, last = steps.end_headings(ends)
    for key, i in ends.index.items():
        if lines.length(key) > 0:
            assert (float(first[i]), float(last[i])) == _headings(lines, key), key
    assert len(undrivable) < len(graph)


def test_curvature_over_several_windows_is_each_windows_and_each_lines_own(berlin_build):
    """Route selection measures bends over five windows on the same lines: the arc lengths, headings and
    search tables are made once for all windows (``wheelbase_curvatures``). Each window's curvatures are
    those of every line measured alone over that window, to the bit."""
    from tavf_mapkit.mesh.swept_path import wheelbase_curvature, wheelbase_curvatures
    from twin.planning.drivable import WINDOWS

    graph = LaneGraph.from_opendrive(load_opendrive(Build.open(berlin_build).xodr))
    batches = LaneLines(graph).scan(sorted(graph.keys))
    points = [batch.points[lo:hi, :2] for batch in batches for lo, hi in zip(batch.at[:-1], batch.at[1:]) if hi - lo > 1]
    points[3] = np.repeat(points[3], 2, axis=0)  # repeated points take their predecessor's curvature
    lane = np.repeat(np.arange(len(points)), [len(p) for p in points])
    together = wheelbase_curvatures(lane, np.concatenate(points), WINDOWS)
    assert len(together) == len(WINDOWS)
    bounds = np.cumsum([0] + [len(p) for p in points])
    for window, curvature in zip(WINDOWS, together):
        for k in range(0, len(points), 7):
            alone = wheelbase_curvature(np.zeros(len(points[k]), dtype=np.int64), points[k], window)
            assert np.array_equal(curvature[bounds[k]:bounds[k + 1]], alone), (window, k)
    assert not np.array_equal(together[0], together[-1]) and together[-1].max() > 0  # windows differ
