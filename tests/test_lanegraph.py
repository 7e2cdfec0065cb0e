"""Lane graph: exact topology on a synthetic map, connectivity invariants on real builds."""

from __future__ import annotations

import itertools
import math

import networkx as nx
import numpy as np
import pytest

from tavf_mapkit.lanegraph import LaneGraph, LaneKey, NoRouteError
from tavf_mapkit.opendrive import load_opendrive, loads_opendrive


def _lane(lane_id, width, link="", mark="broken", lane_type="driving"):
    return (f'<lane id="{lane_id}" type="{lane_type}"><link>{link}</link>'
            f'<width sOffset="0" a="{width}" b="0" c="0" d="0"/><roadMark sOffset="0" type="{mark}"/></lane>')


def _road(road_id, x, y, hdg, length, sections, link="", junction="-1", rule=""):
    rule_attr = f' rule="{rule}"' if rule else ""
    return (f'<road id="{road_id}" length="{length}" junction="{junction}"{rule_attr}><link>{link}</link>'
            f'<planView><geometry s="0" x="{x}" y="{y}" hdg="{hdg}" length="{length}"><line/></geometry></planView>'
            f'<lanes>{sections}</lanes></road>')


def _section(s0, left=(), right=()):
    left_xml = f"<left>{''.join(left)}</left>" if left else ""
    right_xml = f"<right>{''.join(right)}</right>" if right else ""
    return f'<laneSection s="{s0}">{left_xml}<center><lane id="0" type="none"/></center>{right_xml}</laneSection>'


def synthetic_map(rule: str = "") -> str:
    """Road 1 (east, two lane sections) meets road 2 (west-pointing) end to end; road 2's start enters
    junction 10, whose connecting road 3 leads into road 4.

    Road 1 section 0 has a broken line between lanes -1 and -2, section 1 a solid one; road 2 a solid one.
    """
    road1 = _road("1", 0, 0, 0, 100, _section(
        0, left=[_lane(1, 3.5, '<predecessor id="1"/>')],
        right=[_lane(-1, 3, '<successor id="-1"/>'), _lane(-2, 3, '<successor id="-2"/>')],
    ) + _section(
        50, left=[_lane(1, 3.5, '<predecessor id="1"/><successor id="-1"/>')],
        right=[_lane(-1, 3, '<predecessor id="-1"/><successor id="1"/>', mark="solid"),
               _lane(-2, 3, '<predecessor id="-2"/><successor id="2"/>')],
    ), link='<successor elementType="road" elementId="2" contactPoint="end"/>', rule=rule)
    road2 = _road("2", 200, 0, math.pi, 100, _section(
        0, left=[_lane(1, 3, '<successor id="-1"/>', mark="solid"), _lane(2, 3, '<successor id="-2"/>')],
        right=[_lane(-1, 3.5, '<successor id="1"/>')],
    ), link='<predecessor elementType="junction" elementId="10"/>'
            '<successor elementType="road" elementId="1" contactPoint="end"/>', rule=rule)
    road3 = _road("3", 200, 0, 0, 20, _section(0, right=[_lane(-1, 3, '<predecessor id="1"/><successor id="-1"/>')]),
                  link='<predecessor elementType="road" elementId="2" contactPoint="start"/>'
                       '<successor elementType="road" elementId="4" contactPoint="start"/>', junction="10", rule=rule)
    road4 = _road("4", 220, 0, 0, 50, _section(0, right=[_lane(-1, 3, '<predecessor id="-1"/>'),
                                                         _lane(-2, 2, lane_type="sidewalk")]),
                  link='<predecessor elementType="junction" elementId="10"/>', rule=rule)
    junction = ('<junction id="10" name="j"><connection id="0" incomingRoad="2" connectingRoad="3" '
                'contactPoint="start"><laneLink from="1" to="-1"/></connection></junction>')
    return ('<?xml version="1.0"?><OpenDRIVE><header revMajor="1" revMinor="6" name="lanegraph"/>'
            f"{road1}{road2}{road3}{road4}{junction}</OpenDRIVE>")


def follow_edges(graph: LaneGraph) -> set[tuple[LaneKey, LaneKey]]:
    return {(a, b) for a, b, kind in graph.edge_list() if kind == "follow"}


K = LaneKey


def test_synthetic_topology_is_exact():
    graph = LaneGraph.from_opendrive(loads_opendrive(synthetic_map()))
    assert set(graph.keys) == {K(0, 0, 1), K(0, 0, -1), K(0, 0, -2), K(0, 1, 1), K(0, 1, -1), K(0, 1, -2),
                               K(1, 0, 1), K(1, 0, 2), K(1, 0, -1), K(2, 0, -1), K(3, 0, -1)}  # no sidewalk
    assert follow_edges(graph) == {
        (K(0, 0, -1), K(0, 1, -1)), (K(0, 0, -2), K(0, 1, -2)),          # lane sections, with s
        (K(0, 1, 1), K(0, 0, 1)),                                         # against s
        (K(0, 1, -1), K(1, 0, 1)), (K(0, 1, -2), K(1, 0, 2)),            # end-to-end contact
        (K(1, 0, -1), K(0, 1, 1)),
        (K(1, 0, 1), K(2, 0, -1)),                                        # junction connection
        (K(2, 0, -1), K(3, 0, -1)),                                       # connecting road -> road 4
    }
    # the broken line of section 0 allows changes both ways, the solid one of section 1 none
    changes = {(a, b, kind) for a, b, kind in graph.edge_list() if kind != "follow"}
    assert changes == {(K(0, 0, -1), K(0, 0, -2), "right"), (K(0, 0, -2), K(0, 0, -1), "left"),
                       }
    assert graph.neighbours(K(0, 1, -1)) == (None, K(0, 1, -2))    # lane 1 runs the other way
    assert graph.neighbours(K(1, 0, 2)) == (K(1, 0, 1), None)      # against s, left is towards the centre
    assert not graph.lane_change_allowed(K(0, 1, -1), "right")
    assert graph.lane_change_allowed(K(0, 0, -1), "right")
    assert graph.successors(K(1, 0, 1)) == [K(2, 0, -1)]
    assert graph.predecessors(K(3, 0, -1)) == [K(2, 0, -1)]


def test_synthetic_route_uses_the_allowed_lane_change():
    graph = LaneGraph.from_opendrive(loads_opendrive(synthetic_map()))
    route = graph.shortest_path(K(0, 0, -2), K(3, 0, -1))
    assert route == [K(0, 0, -2), K(0, 0, -1), K(0, 1, -1), K(1, 0, 1), K(2, 0, -1), K(3, 0, -1)]
    with pytest.raises(NoRouteError, match="no route"):
        graph.shortest_path(K(3, 0, -1), K(0, 0, -1))
    # the only cycle: changing back and forth between the two lanes of section 0 (100 m of lanes together)
    assert graph.largest_strongly_connected() == {K(0, 0, -1), K(0, 0, -2)}


def test_synthetic_centre_lines_lengths_and_directions():
    graph = LaneGraph.from_opendrive(loads_opendrive(synthetic_map()))
    points, s = graph.centerline(K(0, 0, -1), step=10.0)
    np.testing.assert_allclose(points[:, 1], -1.5, atol=1e-9)          # centre of a 3 m lane
    np.testing.assert_allclose(points[[0, -1], 0], [0.0, 50.0], atol=1e-9)
    np.testing.assert_allclose(s, np.linspace(0, 50, 6))
    points, s = graph.centerline(K(0, 1, 1), step=1.0)                # against s: x decreasing
    np.testing.assert_allclose(points[[0, -1], 0], [100.0, 50.0], atol=1e-9)
    np.testing.assert_allclose(points[:, 1], 1.75, atol=1e-9)
    assert s[0] == 100.0 and s[-1] == 50.0
    assert graph.length(K(0, 0, -1)) == pytest.approx(50.0)
    assert graph.start(K(0, 1, 1)) == pytest.approx((100.0, 1.75))
    # road 2 points west: its lane 1 lies south of the x axis and carries eastbound traffic
    points, _ = graph.centerline(K(1, 0, 1))
    assert points[0, 0] < points[-1, 0] and np.allclose(points[:, 1], -1.5)


def test_left_hand_traffic_reverses_every_edge():
    right = LaneGraph.from_opendrive(loads_opendrive(synthetic_map()))
    left = LaneGraph.from_opendrive(loads_opendrive(synthetic_map(rule="LHT")))
    assert follow_edges(left) == {(b, a) for a, b in follow_edges(right)}
    assert not left.drives_with_s(K(0, 0, -1)) and left.drives_with_s(K(0, 0, 1))


def test_other_lane_types_on_request():
    graph = LaneGraph.from_opendrive(loads_opendrive(synthetic_map()), lane_types=("driving", "sidewalk"))
    assert K(3, 0, -2) in graph
    assert graph.neighbours(K(3, 0, -1)) == (None, K(3, 0, -2))


# ------------------------------------------------------------------ real builds

def _reference_pose(road, end):
    x, y, _, heading, _, _ = road.reference_point(0.0 if end == "start" else road.length)
    return np.array([x[0], y[0]]), heading[0]


def _angle(a, b):
    return abs((a - b + math.pi) % (2 * math.pi) - math.pi)


def connectivity_report(odr):
    """Check every follow edge whose roads meet in the file (reference lines within 5 cm and headings within
    1 deg given the contact points: what the validator's contact-point rule accepts). netconvert also writes junction roads that start
    metres away from the road they link to; the graph follows the links, the validator reports the geometry.

    Checked: the lane centres meet within 0.5 m, and the driving directions agree (no U-turn hidden in a
    wrong driving direction). Lane centre headings are not compared: far off a sharply curved reference
    line (a fifth lane on a junction road) the offset curve has a cusp, which is the file's geometry.
    """
    graph = LaneGraph.from_opendrive(odr)
    checked, failures = 0, []
    for a, b in sorted(follow_edges(graph)):
        if a.road_index == b.road_index:
            continue
        end_a = "end" if graph.drives_with_s(a) else "start"
        end_b = "start" if graph.drives_with_s(b) else "end"
        point_a, heading_a = _reference_pose(odr.roads[a.road_index], end_a)
        point_b, heading_b = _reference_pose(odr.roads[b.road_index], end_b)
        # end meets start: the roads continue; start meets start (or end meets end): they point apart
        flip = 0.0 if end_a != end_b else math.pi
        if np.linalg.norm(point_a - point_b) > 0.05 or _angle(heading_a + flip, heading_b) > math.radians(1):
            continue
        # a lane merging into (or splitting from) a neighbour ends beside it, not on it
        if sum(k.road_index == a.road_index for k in graph.predecessors(b)) > 1 \
                or sum(k.road_index == b.road_index for k in graph.successors(a)) > 1:
            continue
        checked += 1
        drive_a = heading_a + (0.0 if graph.drives_with_s(a) else math.pi)
        drive_b = heading_b + (0.0 if graph.drives_with_s(b) else math.pi)
        line_a, _ = graph.centerline(a, 0.5)
        line_b, _ = graph.centerline(b, 0.5)
        gap = float(np.linalg.norm(line_a[-1, :2] - line_b[0, :2]))
        if gap > 0.5 or _angle(drive_a, drive_b) > math.radians(1):
            failures.append((a, b, round(gap, 3), round(math.degrees(_angle(drive_a, drive_b)), 1)))
    return graph, checked, failures


@pytest.mark.slow
@pytest.mark.parametrize("fixture", ["jungfernstieg_build", "tavf_dlr_build"])
def test_real_build_connectivity(fixture, request):
    folder = request.getfixturevalue(fixture)
    odr = load_opendrive(folder / f"{folder.name}.xodr")
    graph, checked, failures = connectivity_report(odr)
    assert checked > 0.5 * len(follow_edges(graph))
    assert failures == []
    # every lane change joins lanes of one road section that run the same way, side by side
    for a, b, kind in graph.edge_list():
        if kind != "follow":
            assert a[:2] == b[:2] and graph.drives_with_s(a) == graph.drives_with_s(b)
            assert abs(abs(a.lane_id) - abs(b.lane_id)) == 1


def _sumo_scc_share(net_path) -> float:
    """Largest strongly connected share of passenger-car lane length in the SUMO network itself (sumolib)."""
    import sumolib

    net = sumolib.net.readNet(str(net_path), withInternal=False)
    graph, length = nx.DiGraph(), {}
    for edge in net.getEdges():
        lanes = [lane for lane in edge.getLanes() if lane.allows("passenger")]
        for lane in lanes:
            length[lane.getID()] = lane.getLength()
            graph.add_node(lane.getID())
            for connection in lane.getOutgoing():
                if connection.getToLane().allows("passenger"):
                    graph.add_edge(lane.getID(), connection.getToLane().getID())
        for a, b in itertools.pairwise(lanes):
            graph.add_edge(a.getID(), b.getID())
            graph.add_edge(b.getID(), a.getID())
    biggest = max(nx.strongly_connected_components(graph), key=lambda c: sum(length[k] for k in c))
    return sum(length[k] for k in biggest) / sum(length.values())


@pytest.mark.slow
@pytest.mark.parametrize("fixture", ["jungfernstieg_build", "tavf_dlr_build"])
def test_largest_strongly_connected_part_matches_the_sumo_network(fixture, request):
    """Both extracts are clipped out of a city, so roads that leave the area are one-way dead ends; the lane
    graph's largest strongly connected share of lane length must agree with SUMO's own lane graph."""
    folder = request.getfixturevalue(fixture)
    graph = LaneGraph.from_opendrive(load_opendrive(folder / f"{folder.name}.xodr"))
    scc = graph.largest_strongly_connected()
    share = sum(graph.length(k) for k in scc) / graph.total_length
    assert share == pytest.approx(_sumo_scc_share(folder / f"{folder.name}.net.xml"), abs=0.04)
    assert share > 0.25
    # inside it, every lane reaches every other one
    some = sorted(scc)
    route = graph.shortest_path(some[0], some[-1])
    assert route[0] == some[0] and route[-1] == some[-1] and set(route) <= scc


# ------------------------------------------------------------------ lane table in bounded chunks

def _whole_map_table(odr, step: float = 1.0):
    """(length, first, last, rows, s, centre) as sampling the whole map in one go gives them."""
    from tavf_mapkit.opendrive.sampling import sample_lanes

    sampling = sample_lanes(odr, step, include_end=True)
    centre = sampling.center_points(with_height=False)
    rows, n = sampling.pair_lane, len(odr.arrays.lane_id)
    segment = np.linalg.norm(np.diff(centre, axis=0), axis=1)
    same = rows[1:] == rows[:-1]
    length = np.bincount(rows[1:][same], weights=segment[same], minlength=n)
    begin = np.searchsorted(rows, np.arange(n), side="left")
    end = np.searchsorted(rows, np.arange(n), side="right") - 1
    return length, centre[begin], centre[end], rows, sampling.s, centre


def _with_budget(odr, max_points: int):
    """The same map with a smaller allocation budget (the real budget object, its ceiling lowered)."""
    from dataclasses import replace

    arrays = odr.arrays
    odr.__dict__["arrays"] = replace(arrays, budget=replace(arrays.budget, max_points=max_points))
    return odr


def test_lane_table_in_tiny_chunks_is_the_whole_map_sampling_to_the_bit(tavf_xodr):
    """A region's lane table is sampled a few hundred thousand lane samples at a time; chunks of 97 samples
    on DLR's TAVF network give exactly the numbers of one pass over the whole map, and the table keeps the
    samples of the requested rows only, in (row, s) order."""
    from tavf_mapkit.lanegraph.geometry import LaneTable

    odr = load_opendrive(tavf_xodr)
    arrays = odr.arrays
    assert np.all(np.diff(arrays.lane_section) >= 0)  # lanes in section order: chunks of sections stay in order
    length, first, last, rows, s, centre = _whole_map_table(odr)
    sampled = np.isin(np.arange(len(length)), rows)
    keep = arrays.lane_type == "driving"
    chunked = LaneTable.build(odr, 1.0, keep=keep, chunk_samples=97)
    np.testing.assert_array_equal(chunked.length, length)
    np.testing.assert_array_equal(chunked.first[sampled], first[sampled])
    np.testing.assert_array_equal(chunked.last[sampled], last[sampled])
    wanted = keep[rows]
    np.testing.assert_array_equal(chunked.sample_row, rows[wanted])
    np.testing.assert_array_equal(chunked.sample_s, s[wanted])
    np.testing.assert_array_equal(chunked.sample_xy, centre[wanted, :2])
    assert chunked.sample_row.dtype == np.int32 and 0 < wanted.sum() < len(rows)
    whole = LaneTable.build(odr, 1.0, keep=keep, chunk_samples=10**9)
    for field in ("length", "first", "last", "sample_row", "sample_s", "sample_xy"):
        np.testing.assert_array_equal(getattr(whole, field), getattr(chunked, field))


def test_lane_graph_of_a_map_over_the_budget_as_a_whole(tavf_xodr):
    """Columbus has 7.3 million samples at 1 m (one lane per section, nearly), over the budget of one
    allocation: the lane graph takes them in chunks within it (here: the TAVF network with a ceiling of half
    its reference-line samples), the same graph as without the lower ceiling; sampling the whole map at once
    is refused, and so is an absurd step for the lane table."""
    from tavf_mapkit.errors import InputError
    from tavf_mapkit.lanegraph.geometry import LaneTable
    from tavf_mapkit.lanegraph.index import LaneIndex
    from tavf_mapkit.opendrive.sampling import sample_lanes

    reference = LaneGraph.from_opendrive(load_opendrive(tavf_xodr))
    total = len(LaneIndex(reference).node)
    samples, _ = _sample_counts(tavf_xodr)
    tight = _with_budget(load_opendrive(tavf_xodr), max_points=samples // 2)
    with pytest.raises(InputError, match="sampling every 1 m would allocate"):
        sample_lanes(tight, 1.0)
    with pytest.raises(InputError, match=r"sampling every 0.001 m would allocate .* budget of 2.5e\+07"):
        LaneTable.build(tight, 0.001)
    graph = LaneGraph.from_opendrive(tight)
    assert set(graph.keys) == set(reference.keys) and set(graph.edge_list()) == set(reference.edge_list())
    assert [graph.length(k) for k in graph.keys] == [reference.length(k) for k in graph.keys]
    index = LaneIndex(graph)
    assert len(index.node) == total
    probe = index.xy[::50]
    np.testing.assert_array_equal(index.nearest(probe[:, 0], probe[:, 1]).node,
                                  LaneIndex(reference).nearest(probe[:, 0], probe[:, 1]).node)


def _sample_counts(path) -> tuple[int, int]:
    """(samples of the reference lines, lane samples) at 1 m."""
    from tavf_mapkit.opendrive.sampling import sample_lanes

    sampling = sample_lanes(load_opendrive(path), 1.0)
    return len(sampling.sample_s), len(sampling.pair_lane)


def test_s_values_of_many_sections_at_once_are_each_sections_own():
    """``centerlines`` spaces the s values of a region's lane sections at once (``sections_s_values``), the
    same bits as ``np.linspace`` gives each section (``section_s_values``): sections of any length and
    offset, exactly a step long, shorter than the rounding margin, of zero and negative length."""
    from tavf_mapkit.lanegraph.geometry import section_s_values, sections_s_values

    rng = np.random.default_rng(5)
    s0 = rng.uniform(0, 5000, 20_000)
    s0[::3] = np.round(s0[::3], 2)
    length = np.r_[rng.uniform(0, 300, 19_990), [0.0, -1.0, 1e-300, 1e-9, 2e-9, 0.5, 1.0, 1.0000000001, 3.0, 7.0]]
    for step in (1.0, 0.5, 0.3):
        values, counts = sections_s_values(s0, s0 + length, step)
        assert counts.sum() == len(values)
        for a, b, part in zip(s0.tolist(), (s0 + length).tolist(), np.split(values, np.cumsum(counts)[:-1])):
            assert part.tobytes() == section_s_values(a, b, step).tobytes(), (a, b, step)


def test_centre_lines_by_section_are_each_lanes_own_to_the_bit(sample_build_dir):
    """``section_centre_lines`` evaluates the reference line once per section and each border once (a lane's
    inner border is its neighbour's outer one); every lane's points are still ``centre_points`` of that lane
    alone at its section's s, to the bit: all lane types (sidewalks outside driving lanes, several lanes a
    side), rows asked in any order and without their inner neighbours."""
    from tavf_mapkit.lanegraph.geometry import centre_points, section_centre_lines, sections_s_values
    from twin.sim.build import Build

    wide = _road("1", 0, 0, 0.3, 40, _section(0, left=[_lane(1, 3.0), _lane(2, 2.5, lane_type="sidewalk")],
                                              right=[_lane(-1, 3.2), _lane(-2, 3.0), _lane(-3, 2.0, lane_type="sidewalk")])
                 + _section(25.5, right=[_lane(-1, 3.1), _lane(-2, 2.9)]))
    header = '<header revMajor="1" revMinor="6"/>'
    for odr in (loads_opendrive(f'<OpenDRIVE>{header}{wide}</OpenDRIVE>'),
                load_opendrive(Build.open(sample_build_dir).xodr)):
        arrays = odr.arrays
        assert arrays.lane_rank.max() >= 1  # lanes whose inner border is another lane's outer one
        every = np.arange(len(arrays.lane_id))
        some = np.random.default_rng(3).permutation(every)
        some = some[arrays.lane_rank[some] > 0][:40]  # outer lanes alone: their inner neighbours are not asked
        for rows in (every, some):
            points, s, counts = section_centre_lines(odr, rows, 1.0)
            section = arrays.lane_section[rows]
            want_s, want_counts = sections_s_values(arrays.section_s0[section], arrays.section_end[section], 1.0)
            assert np.array_equal(counts, want_counts) and np.array_equal(s, want_s)
            assert np.array_equal(points, centre_points(odr, np.repeat(rows, counts), s))
    graph = LaneGraph.from_opendrive(odr)
    keys = graph.keys[::-1]
    flat, _, counts = graph.centerline_arrays(keys)
    for key, points in zip(keys, np.split(flat, np.cumsum(counts)[:-1])):
        assert np.array_equal(points, graph.centerline(key)[0]), key  # reversed where the lane drives against s
