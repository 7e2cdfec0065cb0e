"""Our validator and ASAM's quality checker (asam-qc-opendrive, benchmarks/peers) find the same issues: for every
ASAM rule with a matching rule of ours (docs/validation-rules.md, "ASAM's quality checker"), both name the same
roads -- on a small document with one fault per rule, and on the zoo files where ASAM finds something.

The checker runs once per file (module fixtures, a few seconds each). It runs its semantic rules only on a file
the ASAM schema accepts, and most rules only from OpenDRIVE 1.7 on, so the faults document is written as 1.7
(and read again as 1.8 for the one 1.8 rule). Without the peer the tests skip; under CI=true they fail.
"""

from __future__ import annotations

from collections import defaultdict

import pytest

from benchmarks.peers import asam_qc
from benchmarks.peers.asam_issues import issue_roads
from tavf_mapkit.validate import validate_file
from tests.conftest import peer, shared_path

pytestmark = pytest.mark.slow


def _lanes(right=((-1, "driving", 3.5),), left=(), links=None, level=None, extra=None, s0=0.0, border=None) -> str:
    """One lane section: (id, type, width) per lane; ``links``/``extra``/``border``: XML per lane id."""
    links, level, extra, border = links or {}, level or {}, extra or {}, border or {}

    def lane(lane_id, kind, width):
        link = f"<link>{links[lane_id]}</link>" if lane_id in links else ""
        shape = border.get(lane_id) or f'<width sOffset="0" a="{width!r}" b="0" c="0" d="0"/>'
        return (f'<lane id="{lane_id}" type="{kind}" level="{str(bool(level.get(lane_id))).lower()}">{link}{shape}'
                f'{extra.get(lane_id, "")}</lane>')

    sides = ("<left>" + "".join(lane(*x) for x in left) + "</left>") if left else ""
    sides += '<center><lane id="0" type="none" level="false"/></center>'
    sides += ("<right>" + "".join(lane(*x) for x in right) + "</right>") if right else ""
    return f'<laneSection s="{s0!r}">{sides}</laneSection>'


def _road(road_id, y, x=0.0, hdg=0.0, length=20.0, shape="<line/>", geometries=None, sections=None, link="",
          junction="-1") -> str:
    geometries = geometries or \
        f'<geometry s="0" x="{x!r}" y="{y!r}" hdg="{hdg!r}" length="{length!r}">{shape}</geometry>'
    return (f'<road id="{road_id}" length="{length!r}" junction="{junction}" rule="RHT"><link>{link}</link>'
            f'<planView>{geometries}</planView><lanes>{sections or _lanes()}</lanes></road>')


def _link(tag, kind, element_id, contact=None) -> str:
    return f'<{tag} elementType="{kind}" elementId="{element_id}"' + (f' contactPoint="{contact}"' if contact else "") + "/>"


def faults_document(minor: int) -> str:
    """One fault per ASAM rule, each on its own roads (comments name the ASAM rule)."""
    roads = [
        # lanes_across_lane_sections: road 1's lane -1 names lane -1 of road 2, which does not name it back
        _road(1, 0, link=_link("successor", "road", 2, "start"), sections=_lanes(links={-1: '<successor id="-1"/>'})),
        _road(2, 0, x=20.0, link=_link("predecessor", "road", 1, "end")),
        # is_junction_needed: roads 10 and 11 both start where road 12 ends
        _road(12, 100, link=_link("successor", "road", 10, "start")),
        _road(10, 100, x=20.0, link=_link("predecessor", "road", 12, "end")),
        _road(11, 100, x=20.0, hdg=0.3, link=_link("predecessor", "road", 12, "end")),
        # zero_width_at_start and new_lane_appear: lane -2 appears (width 0) at s = 10, lane -1 links into it
        _road(20, 200, sections=_lanes(links={-1: '<successor id="-2"/>'}) + _lanes(
            right=((-1, "driving", 3.5), (-2, "driving", 0.0)), s0=10.0, links={-2: '<predecessor id="-1"/>'})),
        # level_true_one_side: a level lane inside one that is not
        _road(30, 300, sections=_lanes(right=((-1, "driving", 3.5), (-2, "sidewalk", 2.0)), level={-1: True})),
        # access_no_mix_of_deny_or_allow
        _road(31, 320, sections=_lanes(extra={-1: '<access sOffset="0" rule="allow" restriction="bus"/>'
                                                  '<access sOffset="0" rule="deny" restriction="truck"/>'})),
        # contact_point_no_horizontal_gaps: road 51 starts 1 m beside road 50's end
        _road(50, 500, link=_link("successor", "road", 51, "start"), sections=_lanes(links={-1: '<successor id="-1"/>'})),
        _road(51, 501, x=20.0, link=_link("predecessor", "road", 50, "end"),
              sections=_lanes(links={-1: '<predecessor id="-1"/>'})),
        # parampoly3 length_match / normalized_range (@length 0.5 m long) and arclength_range (curve 1.2 m longer)
        _road(60, 600, length=20.5, geometries='<geometry s="0" x="0" y="600" hdg="0" length="20.5"><paramPoly3 '
              'aU="0" bU="20" cU="0" dU="0" aV="0" bV="0" cV="2" dV="0" pRange="normalized"/></geometry>'),
        _road(61, 610, geometries='<geometry s="0" x="0" y="610" hdg="0" length="20"><paramPoly3 aU="0" bU="1" '
              'cU="0" dU="0" aV="0" bV="0" cV="0.03" dV="0" pRange="arcLength"/></geometry>'),
        # border_overlap_with_inner_lanes: lane -2's outer border crosses lane -1's from s = 6
        _road(70, 700, sections=_lanes(right=((-1, "driving", 0), (-2, "driving", 0)), border={
            -1: '<border sOffset="0" a="-3" b="0" c="0" d="0"/>', -2: '<border sOffset="0" a="-6" b="0.5" c="0" d="0"/>'})),
        # avoid_redundant_info: one line written as two
        _road(80, 800, geometries='<geometry s="0" x="0" y="800" hdg="0" length="10"><line/></geometry>'
                                  '<geometry s="10" x="10" y="800" hdg="0" length="10"><line/></geometry>'),
        # junction 100: roads 40 and 42 meet through connecting road 41. Connection 0's laneLink comes from a lane
        # leaving the junction (one_link_to_incoming, 1.8); connection 1 names 42 as incoming road of 41's start,
        # which is road 40's (start_along_linkage), so 41 has two connections (one_connection_element, 1.7);
        # connection 2's incoming road is the connecting road 41 (connect_road_no_incoming_road)
        _road(40, 400, link=_link("successor", "junction", 100), sections=_lanes(left=((1, "driving", 3.5),))),
        _road(41, 400, x=20.0, junction="100",
              link=_link("predecessor", "road", 40, "end") + _link("successor", "road", 42, "start")),
        _road(42, 400, x=40.0, link=_link("predecessor", "junction", 100), sections=_lanes(left=((1, "driving", 3.5),))),
        _road(43, 450, junction="100"),
    ]
    junction = ('<junction id="100" name="j">'
                '<connection id="0" incomingRoad="40" connectingRoad="41" contactPoint="start">'
                '<laneLink from="1" to="-1"/></connection>'
                '<connection id="1" incomingRoad="42" connectingRoad="41" contactPoint="start">'
                '<laneLink from="1" to="-1"/></connection>'
                '<connection id="2" incomingRoad="41" connectingRoad="43" contactPoint="start">'
                '<laneLink from="-1" to="-1"/></connection></junction>')
    return (f'<?xml version="1.0" encoding="UTF-8"?>\n<OpenDRIVE><header revMajor="1" revMinor="{minor}" '
            'name="asam faults" version="1" date="2026-11-23" north="0" south="0" east="0" west="0"/>'
            + "".join(roads) + junction + "</OpenDRIVE>\n")


#: ASAM checker -> (our rule, the roads ASAM names in the faults document)
FAULTS = {
    "road_lane_link_lanes_across_lane_sections": ("topology.lane-link-symmetry", {"2"}),
    "road_linkage_is_junction_needed": ("topology.junction-needed", {"12"}),
    "road_lane_link_zero_width_at_start": ("topology.zero-width-link", {"20"}),
    "road_lane_link_new_lane_appear": ("topology.appearing-lane-link", {"20"}),
    "road_lane_level_true_one_side": ("structure.lane-level", {"30"}),
    "road_lane_access_no_mix_of_deny_or_allow": ("structure.lane-access", {"31"}),
    "road_geometry_parampoly3_length_match": ("geometry.param-poly3-length", {"60"}),  # pRange normalized
    "road_geometry_parampoly3_normalized_range": ("geometry.param-poly3-length", {"60"}),
    "road_geometry_parampoly3_arclength_range": ("geometry.param-poly3-length", {"61"}),  # pRange arcLength
    "road_lane_border_overlap_with_inner_lanes": ("geometry.border-crossing", {"70"}),
    "performance_avoid_redundant_info": ("geometry.redundant-record", {"80"}),
    "junctions_connection_start_along_linkage": ("topology.connection-contact", {"41"}),
    "junctions_connection_one_connection_element": ("topology.connection-unique", {"41"}),
    "junctions_connection_connect_road_no_incoming_road": ("topology.incoming-road", {"41"}),
}


def _our_roads(xodr, rules=None) -> dict:
    found = defaultdict(set)
    for finding in validate_file(xodr, rules=rules).findings:
        found[finding.rule].add(finding.road)
    return found


def _checked(xodr, folder, minor=None) -> dict:
    """ASAM's roads per checker for ``xodr`` (read as OpenDRIVE 1.``minor`` when given), after making sure the
    schema accepted it and no checker failed."""
    result = asam_qc.check(xodr, folder, peer(asam_qc.program), minor=minor)
    assert "error" not in result, result
    assert "xml_valid_schema" not in result["issues"] and "xml_valid_schema" not in result["skipped"], result["first"]
    stem = f"{xodr.stem}.as-1.{minor}" if minor is not None else xodr.stem
    return issue_roads(folder / f"{stem}.xqar", folder / f"{stem}.xodr" if minor is not None else xodr)


@pytest.fixture(scope="module")
def faults(tmp_path_factory):
    folder = tmp_path_factory.mktemp("asam-faults")
    xodr = folder / "faults.xodr"
    xodr.write_text(faults_document(7))
    return xodr, _checked(xodr, folder), _checked(xodr, folder, minor=8), _our_roads(xodr)


@pytest.mark.parametrize("checker", sorted(FAULTS))
def test_asam_finds_each_fault_where_it_was_put(faults, checker):
    _, asam, _, _ = faults
    assert asam.get(checker) == FAULTS[checker][1]


@pytest.mark.parametrize("rule", sorted({rule for rule, _ in FAULTS.values()}))
def test_our_matching_rule_names_the_same_roads(faults, rule):
    """Our rule finds what the ASAM rules mapped to it find, and nothing else in the document."""
    _, asam, _, ours = faults
    assert ours[rule] == set().union(*(asam.get(checker, set()) for checker, (mapped, _) in FAULTS.items()
                                       if mapped == rule))


def test_asam_finds_nothing_we_do_not(faults):
    """Every ASAM checker that found something in the faults document is one of FAULTS or the two below."""
    _, asam, asam_1_8, _ = faults
    assert set(asam) <= set(FAULTS) | {"lane_smoothness_contact_point_no_horizontal_gaps"}, asam
    assert set(asam_1_8) - set(asam) == {"junctions_connection_one_link_to_incoming"}, asam_1_8


def test_lane_direction_in_junctions_as_in_opendrive_1_8(faults):
    """junctions.connection.one_link_to_incoming is a rule from 1.8 on: the same document read as 1.8."""
    _, _, asam_1_8, ours = faults
    assert asam_1_8["junctions_connection_one_link_to_incoming"] == ours["topology.junction-lane-direction"] == {"41"}


def test_linked_lanes_meet(faults):
    """lane_smoothness.contact_point_no_horizontal_gaps and topology.contact-gap both find road 51 starting 1 m
    beside road 50 and the junction lane of road 40 that does not meet lane -1 of road 41. Where they differ, by
    design: ASAM also compares lanes across lane sections of one road (road 20, the appearing lane: ours is
    topology.appearing-lane-link); ours also compares the lanes of a junction connection that contradicts the
    connecting road's own links (road 42's lane 1 and lane -1 of road 41, 20 m apart), which ASAM skips."""
    _, asam, _, ours = faults
    smooth = asam["lane_smoothness_contact_point_no_horizontal_gaps"]
    assert smooth & ours["topology.contact-gap"] == {"40", "50"}
    assert smooth - ours["topology.contact-gap"] == {"20"} and "20" in ours["topology.appearing-lane-link"]
    assert ours["topology.contact-gap"] - smooth == {"42"}


@pytest.fixture(scope="module")
def zoo_files(tmp_path_factory):
    """ASAM on the zoo's OpenDRIVE files where it finds issues of a mapped rule in a few seconds: CARLA Town03 as
    it is (1.4) and esmini's left-hand route test network read as 1.8."""
    folder = tmp_path_factory.mktemp("asam-zoo")
    town03 = shared_path("zoo", "xodr", "carla_Town03.xodr")
    esmini = shared_path("zoo", "xodr", "esmini_route_strategy_test_road_LHT.xodr")
    return {"town03": (_checked(town03, folder), _our_roads(town03, "topology.lane-link-symmetry")),
            "esmini": (_checked(esmini, folder, minor=8), _our_roads(esmini, "topology.junction-lane-direction"))}


def test_one_sided_lane_links_in_carla_town03(zoo_files):
    asam, ours = zoo_files["town03"]
    assert set(asam) == {"road_lane_link_lanes_across_lane_sections"}, asam
    assert asam["road_lane_link_lanes_across_lane_sections"] == ours["topology.lane-link-symmetry"] == \
        {"5", "14", "42", "45"}


def test_lane_links_against_the_driving_direction_in_esmini_lht(zoo_files):
    """esmini's left-hand copy of its route test network keeps the right-hand network's junction laneLinks: all 48
    run against the driving direction (12 connecting roads)."""
    asam, ours = zoo_files["esmini"]
    assert set(asam) == {"junctions_connection_one_link_to_incoming"}, asam
    assert asam["junctions_connection_one_link_to_incoming"] == ours["topology.junction-lane-direction"]
    assert len(ours["topology.junction-lane-direction"]) == 12
