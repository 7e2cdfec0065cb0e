"""Connecting roads meet the lanes they link after the opendrive stage's repair (repair_contacts), duplicate
controllers become one (repair_controllers), and repairing a repaired file changes nothing.

The checks evaluate lane borders with the Road API (not the sampler the repair itself uses) on files written
by our writer and read back by our reader."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from tavf_mapkit.opendrive import load_opendrive
from tavf_mapkit.opendrive.connecting_curve import reverses
from tavf_mapkit.opendrive.geometry import param_poly3_length
from tavf_mapkit.opendrive.repair_contacts import (
    DROPPED_JUNCTION,
    DROPPED_LINK,
    REBUILT_CONNECTING_ROAD,
    REFITTED_LANE_WIDTHS,
    SPLIT_CONNECTING_ROAD,
    end_table,
    repair_contacts,
)
from tavf_mapkit.opendrive.repair_controllers import MERGED_CONTROLLERS, repair_controllers
from tavf_mapkit.opendrive.writer import to_xml, write_opendrive
from tavf_mapkit.validate import validate_file

POSITION = 1e-3  # m
HEADING = math.radians(0.1)


def _lanes(widths, links=None, offset=0.0) -> str:
    """A lane section of right lanes -1, -2, ... with constant widths (links: [(pred, succ)] per lane)."""
    lanes = []
    for k, width in enumerate(widths):
        link = ""
        if links is not None:
            pred, succ = links[k]
            link = f'<link><predecessor id="{pred}"/><successor id="{succ}"/></link>'
        lanes.append(f'<lane id="{-(k + 1)}" type="driving" level="false">{link}'
                     f'<width sOffset="0" a="{width!r}" b="0" c="0" d="0"/></lane>')
    lane_offset = f'<laneOffset s="0" a="{offset!r}" b="0" c="0" d="0"/>' if offset else ""
    return (f'{lane_offset}<laneSection s="0"><center><lane id="0" type="none" level="false"/></center>'
            f'<right>{"".join(lanes)}</right></laneSection>')


def _line(x, y, hdg, length) -> str:
    return f'<geometry s="0" x="{x!r}" y="{y!r}" hdg="{hdg!r}" length="{length!r}"><line/></geometry>'


def _road(road_id, length, geometry, lanes, links, junction="-1") -> str:
    return (f'<road id="{road_id}" length="{length!r}" junction="{junction}"><link>{links}</link>'
            f'<planView>{geometry}</planView><lanes>{lanes}</lanes></road>')


def junction_document(p_pose, p_widths, s_pose, s_widths, lane_pairs, c_geometry=None, c_widths=None,
                      c_offset=0.0, controllers="") -> str:
    """Road 1 (incoming, 30 m, ends at ``p_pose``) -> connecting road 3 in junction 9 -> road 2 (outgoing, 30 m,
    starts at ``s_pose``); road 3's lanes link lane_pairs [(lane of 1, lane of 2)] and, unless given, it is a
    straight line between the two reference points with road 1's widths (netconvert's fallback)."""
    px, py, ph = p_pose
    sx, sy, sh = s_pose
    start = (px - 30 * math.cos(ph), py - 30 * math.sin(ph))
    p = _road("1", 30.0, _line(*start, ph, 30.0), _lanes(p_widths),
              '<successor elementType="junction" elementId="9"/>')
    s = _road("2", 30.0, _line(sx, sy, sh, 30.0), _lanes(s_widths),
              '<predecessor elementType="junction" elementId="9"/>')
    if c_geometry is None:
        chord = math.hypot(sx - px, sy - py)
        c_geometry, c_length = _line(px, py, math.atan2(sy - py, sx - px), chord), chord
    else:
        c_geometry, c_length = c_geometry
    widths = c_widths or [p_widths[-a - 1] for a, _ in lane_pairs]
    c = _road("3", c_length, c_geometry, _lanes(widths, lane_pairs, c_offset),
              '<predecessor elementType="road" elementId="1" contactPoint="end"/>'
              '<successor elementType="road" elementId="2" contactPoint="start"/>', junction="9")
    links = "".join(f'<laneLink from="{a}" to="{-(k + 1)}"/>' for k, (a, _) in enumerate(lane_pairs))
    junction = (f'<junction id="9" name="j"><connection id="0" incomingRoad="1" connectingRoad="3" '
                f'contactPoint="start">{links}</connection></junction>')
    return (f'<?xml version="1.0" encoding="UTF-8"?><OpenDRIVE><header revMajor="1" revMinor="4" name="t"/>'
            f'{p}{s}{c}{controllers}{junction}</OpenDRIVE>')


def _load(tmp_path, text: str, name: str = "map.xodr"):
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return load_opendrive(path)


def _reread(tmp_path, odr, name="repaired.xodr"):
    path = tmp_path / name
    write_opendrive(odr, path)
    return load_opendrive(path)


def _border_points(road, s):
    """lane id -> (inner xy, outer xy) of every side lane of the road's only/first-or-last section at s."""
    k = 0 if s == 0 else len(road.lane_sections) - 1
    borders = road.lane_borders(k, np.array([s]))
    out = {}
    for lane in road.lane_sections[k].side_lanes:
        t = np.array([borders[lane.id - lane.side][0], borders[lane.id][0]])
        points = road.surface_point(np.array([s, s]), t)[:, :2]
        out[lane.id] = (points[0], points[1])
    return out


def contact_misfit(odr, road_id: str) -> tuple[float, float]:
    """(largest border distance, largest heading break) of a connecting road against its road links' ends."""
    road = odr.road_by_id[road_id]
    distance, heading = 0.0, 0.0
    for link, s, lane_target in ((road.predecessor, 0.0, "predecessor"), (road.successor, road.length, "successor")):
        other = odr.road_by_id[link.element_id]
        other_s = 0.0 if link.contact_point == "start" else other.length
        mine, theirs = _border_points(road, s), _border_points(other, other_s)
        for lane in road.lane_sections[0].side_lanes:
            target = getattr(lane, lane_target)
            for a, b in zip(mine[lane.id], theirs[target]):
                distance = max(distance, float(np.hypot(*(a - b))))
        _, _, h_mine, _ = road.reference_line.evaluate([s])
        _, _, h_theirs, _ = other.reference_line.evaluate([other_s])
        flip = 0.0 if (link.contact_point == "end") == (s == 0.0) else math.pi
        heading = max(heading, abs((h_mine[0] - h_theirs[0] - flip + math.pi) % (2 * math.pi) - math.pi))
    return distance, heading


def _assert_exact_lengths(road):
    for g in road.reference_line.geometries:
        if g.params and len(g.params) == 9:
            true = float(param_poly3_length(np.array([g.params]), np.array([1.0 if g.params[8] > 0.5 else g.length]))[0])
            assert abs(true - g.length) < 1e-9, (road.id, true, g.length)
    assert abs(sum(g.length for g in road.reference_line.geometries) - road.length) < 1e-9


def _forward_case():
    """Incoming road's end anywhere; the outgoing road starts ahead of it (within 60 degrees of its heading)
    with a heading within 60 degrees of the chord: a turn or a lane shift, never a reversal."""
    lanes = st.integers(1, 3)
    return st.tuples(
        st.floats(-500, 500), st.floats(-500, 500), st.floats(-math.pi, math.pi),  # road 1's end
        st.floats(2.0, 40.0), st.floats(-math.radians(60), math.radians(60)),  # chord length, bearing
        st.floats(-math.radians(60), math.radians(60)),  # outgoing heading relative to the chord
        lanes, st.lists(st.floats(2.5, 4.5), min_size=3, max_size=3),
        st.lists(st.floats(2.5, 4.5), min_size=3, max_size=3),
    )


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(case=_forward_case())
def test_repaired_connecting_roads_meet_their_neighbours(tmp_path, case):
    px, py, ph, chord, bearing, relative, n, p_widths, s_widths = case
    sx, sy = px + chord * math.cos(ph + bearing), py + chord * math.sin(ph + bearing)
    sh = ph + bearing + relative
    # the connecting lanes continue the outer lanes of road 1 into the inner lanes of road 2
    pairs = [(-(k + 1), -(k + 1)) for k in range(n)]
    # a right turn whose arc is tighter than the lanes are wide folds their outer borders: no sensible curve
    # exists there (the repair drops such links, tested below), so this property is about the turns a car takes
    turn = bearing + relative
    radius = chord / (2.0 * math.sin(abs(turn) / 2.0)) if abs(turn) > 1e-9 else math.inf
    assume(turn >= 0.0 or radius > sum(max(p, q) for p, q in zip(p_widths[:n], s_widths[:n])) + 1.0)
    odr = _load(tmp_path, junction_document((px, py, ph), p_widths, (sx, sy, sh), s_widths, pairs))
    repaired, repairs = repair_contacts(odr)
    # a straight road that already heads where it should only needs its widths (or nothing)
    assert [r.action for r in repairs] in ([REBUILT_CONNECTING_ROAD], [REFITTED_LANE_WIDTHS], [])
    reread = _reread(tmp_path, repaired)
    distance, heading = contact_misfit(reread, "3")
    assert distance <= POSITION and heading <= HEADING, (distance, math.degrees(heading))
    _assert_exact_lengths(reread.road_by_id["3"])


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(x=st.floats(-500, 500), y=st.floats(-500, 500), h=st.floats(-math.pi, math.pi),
       width=st.floats(2.5, 6.0), error=st.sampled_from([math.atan(0.5), math.pi - math.atan(0.5)]))
def test_turnarounds_become_u_turns_that_meet_both_lanes(tmp_path, x, y, h, width, error):
    """netconvert's turnaround: a Bezier leaving the incoming lane 26.57 degrees off (153.43 mirrored in a
    left-hand network) onto the opposite road; after the repair its lane meets both lanes exactly."""
    # road 2 runs back beside road 1 (a two-way street's other direction shares its reference line)
    back = h + math.pi
    # netconvert's U-turn: reference line at the outer border, lane offset = width, quadratic Bezier
    ox, oy = x + width * math.sin(h), y - width * math.cos(h)  # outer border of road 1's lane -1
    q = 2 * width  # chord to the outer border of road 2's lane -1
    bezier = (f'<geometry s="0" x="{ox!r}" y="{oy!r}" hdg="{h + error!r}" length="9.0"><paramPoly3 aU="0" '
              f'bU="{2 * q * math.cos(-error)!r}" cU="0" dU="0" aV="0" bV="{2 * q * math.sin(-error)!r}" cV="0" '
              f'dV="0" pRange="normalized"/></geometry>', 9.0)
    odr = _load(tmp_path, junction_document((x, y, h), [width], (x, y, back), [width], [(-1, -1)],
                                            c_geometry=bezier, c_offset=width))
    before, _ = contact_misfit(odr, "3")
    assert before > 1.0
    repaired, repairs = repair_contacts(odr)
    assert [r.action for r in repairs] == [REBUILT_CONNECTING_ROAD]
    reread = _reread(tmp_path, repaired)
    distance, heading = contact_misfit(reread, "3")
    assert distance <= POSITION and heading <= HEADING
    # the reference line runs round the outside: a near semicircle of radius ``width`` (pi r = 3.14 r)
    assert 3.1 * width < reread.road_by_id["3"].length < 3.3 * width


def test_a_merge_written_as_parallel_lanes_is_split_into_two_roads(tmp_path):
    """Lanes -1 and -2 of road 1 both continue into lane -1 of road 2 (netconvert writes them as one road with
    two parallel lanes): lane -2 becomes a connecting road of its own with its own junction connection."""
    odr = _load(tmp_path, junction_document((0, 0, 0), [3.2, 3.2], (20, 0, 0), [3.2], [(-1, -1), (-2, -1)]))
    repaired, repairs = repair_contacts(odr)
    assert sorted(r.action for r in repairs) == [REBUILT_CONNECTING_ROAD, SPLIT_CONNECTING_ROAD]
    split = next(r for r in repairs if r.action == SPLIT_CONNECTING_ROAD)
    assert split.detail == ("lanes -2 of the road between road 1 and road 2 are new connecting road 4: their "
                            "lanes are not beside those of lanes -1 at both ends (lanes merging or splitting)")
    reread = _reread(tmp_path, repaired)
    new = reread.road_by_id["4"]
    assert new.in_junction and [lane.id for lane in new.lane_sections[0].side_lanes] == [-1]
    assert (new.lane_sections[0].by_id[-1].predecessor, new.lane_sections[0].by_id[-1].successor) == (-2, -1)
    connections = {c.connecting_road: c for c in reread.junction_by_id["9"].connections}
    assert [(link.from_lane, link.to_lane) for link in connections["3"].lane_links] == [(-1, -1)]
    assert [(link.from_lane, link.to_lane) for link in connections["4"].lane_links] == [(-2, -1)]
    for road_id in ("3", "4"):
        distance, heading = contact_misfit(reread, road_id)
        assert distance <= POSITION and heading <= HEADING


def test_a_link_without_a_sensible_curve_is_dropped_and_named(tmp_path):
    """Road 2 starts 5 m behind road 1's end, running the same way (Perth: two overlapping stubs): no road
    can join them, so the connecting road, its connection and the junction left empty go."""
    odr = _load(tmp_path, junction_document((0, 0, 0), [4.0], (-5, 0, 0), [4.0], [(-1, -1)]))
    repaired, repairs = repair_contacts(odr)
    assert [r.action for r in repairs] == [DROPPED_LINK, DROPPED_JUNCTION]
    assert str(repairs[0]) == (
        "line 1: road 3: dropped the link between road 1 and road 2 through lanes -1 (road and junction connection): no "
        "sensible connecting road, the lanes it joins lie behind one another (both ends head 180 degrees or more "
        "away from the other end)")
    assert str(repairs[1]) == "line 1: dropped junction 9: no connection is left in it"
    assert sorted(repaired.road_by_id) == ["1", "2"] and not repaired.junctions
    assert repaired.road_by_id["1"].successor is None and repaired.road_by_id["2"].predecessor is None


def test_a_connecting_road_that_reverses_on_itself_is_rebuilt(tmp_path):
    """A connecting road that meets both neighbours exactly but whose paramPoly3 runs forward, back and forward
    again along one line (two cusps; netconvert draws some junction curves with a cusp: London road 9919) is
    rebuilt from lane border to lane border like one that misses them; no chain of arcs, and no lane, follows
    a cusp."""
    cusp = (0.0, 12.6, -30.0, 20.0, 0.0, 0.0, 0.0, 0.0)  # u' = 60 (p - 0.3) (p - 0.7); u(1) = 2.6
    uv = " ".join(f'{k}="{v!r}"' for k, v in zip(("aU", "bU", "cU", "dU", "aV", "bV", "cV", "dV"), cusp))
    length = float(param_poly3_length(np.array([cusp + (1.0,)]), np.array([1.0]))[0])
    geometry = (f'<geometry s="0" x="0" y="0" hdg="0" length="{length!r}"><paramPoly3 {uv} '
                'pRange="normalized"/></geometry>', length)
    odr = _load(tmp_path, junction_document((0, 0, 0), [3.5], (2.6, 0, 0), [3.5], [(-1, -1)], c_geometry=geometry))
    distance, heading = contact_misfit(odr, "3")
    assert distance <= POSITION and heading <= HEADING  # it meets its neighbours: only the cusp is wrong
    repaired, repairs = repair_contacts(odr)
    assert [str(r) for r in repairs] == [
        "line 1: road 3: between road 1 and road 2: its reference line reversed on itself (a cusp); new reference "
        "line (paramPoly3 of 2.6 m) from lane border to lane border"]
    reread = _reread(tmp_path, repaired)
    distance, heading = contact_misfit(reread, "3")
    assert distance <= POSITION and heading <= HEADING
    assert not reverses(np.array(reread.road_by_id["3"].reference_line.geometries[0].params))[0]
    assert repair_contacts(reread)[1] == []


def test_only_the_widths_are_refitted_where_the_reference_line_is_right(tmp_path):
    """A straight connecting road whose lane narrows 3.25 -> 2.50 m with netconvert's two-decimal slope:
    the reference line stays, the width becomes a cubic from one lane's width to the other's."""
    length = 13.0
    # netconvert: a + b s with b = (2.50 - 3.25) / 13 = -0.0577 written as -0.06
    text = junction_document((0, 0, 0), [3.25], (length, 0, 0), [2.5], [(-1, -1)]).replace(
        'a="3.25" b="0" c="0" d="0"/></lane></right></laneSection></lanes></road><junction',
        'a="3.25" b="-0.06" c="0" d="0"/></lane></right></laneSection></lanes></road><junction')
    odr = _load(tmp_path, text)
    before, _ = contact_misfit(odr, "3")
    assert before == pytest.approx(0.03, abs=1e-6)
    repaired, repairs = repair_contacts(odr)
    assert [r.action for r in repairs] == [REFITTED_LANE_WIDTHS]
    reread = _reread(tmp_path, repaired)
    road = reread.road_by_id["3"]
    assert road.reference_line.geometries == odr.road_by_id["3"].reference_line.geometries
    distance, heading = contact_misfit(reread, "3")
    assert distance <= POSITION and heading <= HEADING


def test_the_end_table_holds_every_roads_ends_as_the_road_api_evaluates_them(tmp_path):
    """The repair's table of road ends (made on demand from one sampling of every road's two ends, not a dict
    of RoadEnds: 600 MB on Columbus) gives each road's reference point, heading and every lane's borders at
    s = 0 and s = length as the Road API puts them; a road it does not know is not in it."""
    text = junction_document((3, 4, 0.3), [3.0, 3.5, 2.75], (25, 18, 1.2), [3.2, 3.1, 3.6],
                             [(-1, -1), (-2, -2), (-3, -3)])
    odr = _load(tmp_path, text)
    table = end_table(odr)
    for road in odr.roads:
        for end, s in (("start", 0.0), ("end", road.length)):
            there = table[(road.id, end)]
            x, y, heading, _ = road.reference_line.evaluate([s])
            assert np.hypot(there.xy[0] - x[0], there.xy[1] - y[0]) < 1e-9
            assert abs(there.heading - heading[0]) < 1e-12
            expected = _border_points(road, s)
            assert there.borders.keys() == expected.keys(), (road.id, end)
            for lane, (inner, outer) in expected.items():
                assert np.hypot(*(there.borders[lane][0] - inner)) < 1e-9, (road.id, end, lane)
                assert np.hypot(*(there.borders[lane][1] - outer)) < 1e-9, (road.id, end, lane)
    assert ("1", "start") in table and ("nowhere", "start") not in table and ("1", "middle") not in table
    with pytest.raises(KeyError):
        table[("nowhere", "end")]


def test_repairing_a_repaired_file_changes_nothing(tmp_path):
    text = junction_document((3, 4, 0.3), [3.0, 3.5], (25, 18, 1.2), [3.2, 3.1], [(-1, -1), (-2, -2)])
    odr = _load(tmp_path, text)
    repaired, repairs = repair_contacts(odr)
    assert repairs
    once = tmp_path / "once.xodr"
    write_opendrive(repaired, once)
    again, more = repair_contacts(load_opendrive(once))
    assert more == []
    assert to_xml(again) == once.read_bytes()


def test_duplicate_controllers_are_merged_and_the_validator_names_them(tmp_path):
    controllers = ('<controller id="joined1"><control signalId="a"/><control signalId="b"/></controller>'
                   '<controller id="joined1"><control signalId="a"/><control signalId="c"/></controller>'
                   '<controller id="solo"><control signalId="d"/></controller>')
    text = junction_document((0, 0, 0), [3.0], (20, 0, 0), [3.0], [(-1, -1)], controllers=controllers)
    path = tmp_path / "raw.xodr"
    path.write_text(text, encoding="utf-8")
    report = validate_file(path, rules="topology.duplicate-id")
    assert [f.message for f in report.findings] == ["controller id 'joined1' is used 2 times"]
    repaired, repairs = repair_controllers(load_opendrive(path))
    assert [str(r) for r in repairs] == ["controller 'joined1' was written 2 times; merged into one with 3 "
                                         "controls"]
    assert [(c.id, c.signal_ids) for c in repaired.controllers] == [("joined1", ("a", "b", "c")), ("solo", ("d",))]
    write_opendrive(repaired, tmp_path / "fixed.xodr")
    assert validate_file(tmp_path / "fixed.xodr", rules="topology.duplicate-id").findings == ()


ZOO_BUILDS = {
    "berlin": ("zoo", "osm", "DE_berlin_neukoelln.osm.gz"),
    "perth": ("zoo", "osm", "AU_perth_peanut_roundabout_LHT.osm.gz"),
    "taipei": ("zoo", "osm", "TW_taipei.osm.gz"),
    "tavf-dlr": ("hamburg", "tavf_dlr_sumo_net", "network.net.xml.gz"),
}


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(ZOO_BUILDS))
def test_zoo_builds_validate_without_errors(tmp_path, shared, name):
    """`mapkit build` (up to the opendrive stage) of zoo maps whose netconvert output had 8-170 errors
    (contact gaps, stub lengths, duplicate controllers): its NAME.xodr validates with no error."""
    pipeline = tmp_path / "quick.toml"
    pipeline.write_text('[pipeline]\nstages = ["extract", "netconvert", "opendrive"]\n', encoding="utf-8")
    out = tmp_path / name
    mapkit = str(Path(sys.executable).parent / "mapkit")
    result = subprocess.run([mapkit, "build", str(shared(*ZOO_BUILDS[name])),
                             "--pipeline", str(pipeline), "-o", str(out), "-q"], capture_output=True, text=True,
                            timeout=600)
    assert result.returncode == 0, result.stderr
    report = validate_file(out / f"{name}.xodr")
    errors = [f"{f.rule}: road {f.road}: {f.message}" for f in report.findings if f.severity == "error"]
    assert errors == []
