"""``mapkit export --to lanelet2`` checked by the real Lanelet2 library (the PyPI wheel, ``.[test]``).

On a synthetic road with every feature at a known place, on the sample build, on esmini's left-hand-traffic road
and (slow) on the TAVF and Jungfernstieg builds: the file loads with no errors at our origin; the routing graph of
Lanelet2's German vehicle rules has exactly our lane graph's successors and lane changes (and the same reachable
sets); the lanelets' centre lines lie within 5 cm of our lane centres; neighbours share their bound way and no two
nodes lie within 1 mm but where a lane ends on a point of a section no link joins it to (one node there could
make Lanelet2 read a successor); lanelets run in the driving direction, also under ``rule="LHT"``.
"""

from __future__ import annotations

import itertools
import os
import re
import time
from functools import cached_property
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from xodr_factory import document, road_xml

from tavf_mapkit.cli.main import cli
from tavf_mapkit.lanegraph import LaneGraph, LaneKey
from tavf_mapkit.lanelet2_export import export_lanelet2
from tavf_mapkit.lanelet2_export.mapping import VEHICLE_LANE_TYPE_NAMES
from tavf_mapkit.opendrive import load_opendrive

ESMINI_LHT = ("zoo", "xodr", "esmini_e6mini-lht_LHT.xodr")
CENTRE_TOLERANCE = 0.05  # m, the issue's bound between Lanelet2's centre lines and ours


@pytest.fixture(scope="module")
def lanelet2():
    try:
        import lanelet2
    except ImportError:
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail("lanelet2 is not installed in CI: .ci/run installs '.[test]', which lists it")
        pytest.skip("lanelet2 (PyPI wheel, in the test extra) is not installed")
    return lanelet2


# -- a synthetic road with every feature at a known place --------------------------------------------------------

def _lane(lane_id, kind, width, mark="none", extra="", link=""):
    link = f'<link><{link} id="{lane_id}"/></link>' if link else ""
    return (f'<lane id="{lane_id}" type="{kind}" level="false">{link}'
            f'<width sOffset="0" a="{width}" b="0" c="0" d="0"/>'
            f'<roadMark sOffset="0" type="{mark}" weight="standard" color="standard" width="0.12"/>{extra}</lane>')


def _section(s0: float, minus_one_mark: str, link: str) -> str:
    speed = '<speed sOffset="0" max="50" unit="km/h"/>'
    raised = '<height sOffset="0" inner="0.12" outer="0.12"/>'
    centre = ('<lane id="0" type="none" level="false"><roadMark sOffset="0" type="solid solid" weight="standard" '
              'color="standard" width="0.12"/></lane>')
    left = _lane(1, "driving", 3.5, "solid broken", link=link) + _lane(2, "driving", 3.5, "solid", link=link)
    right = (_lane(-1, "driving", 3.25, minus_one_mark, speed, link)
             + _lane(-2, "driving", 3.25, "solid", link=link)
             + _lane(-3, "biking", 1.5, link=link) + _lane(-4, "sidewalk", 2.0, extra=raised, link=link))
    return f"""
        <laneSection s="{s0}">
          <left>{left}</left>
          <center>{centre}</center>
          <right>{right}</right>
        </laneSection>"""


SIGNALS = """
    <signals>
      <signal id="light1" s="95" t="-4" orientation="+" dynamic="yes" zOffset="4.5" country="OpenDRIVE"
              type="1000001" subtype="-1" height="0.8" width="0.3">
        <validity fromLane="-2" toLane="-1"/>
      </signal>
      <signal id="stop1" s="10" t="8" orientation="-" dynamic="no" zOffset="1.5" country="DE" type="206"
              subtype="-1" height="0.6" width="0.6"/>
    </signals>"""
GEOREFERENCE = ("<geoReference><![CDATA[+proj=tmerc +lat_0=53.55 +lon_0=10.0 +k=1 +x_0=0 +y_0=0 +ellps=WGS84 "
                "+units=m +no_defs]]></geoReference>")


def synthetic_xodr(rule: str = "RHT") -> str:
    """100 m of straight road along x: left lanes 1, 2 (driving), right -1, -2 (driving), -3 (biking), -4 (raised
    sidewalk); two lane sections (marks between -1 and -2: broken, then solid); a traffic light over -1/-2 at
    s=95 and a stop sign for the left lanes at s=10; speed 50 km/h on -1, 30 km/h from the road type."""
    road = road_xml('<geometry s="0" x="0" y="0" hdg="0" length="100"><line/></geometry>', 100.0,
                    lanes=_section(0, "broken", "successor") + _section(50, "solid", "predecessor"),
                    extra='<type s="0" type="town"><speed max="30" unit="km/h"/></type>')
    road = road.replace("</lanes>", "</lanes>" + SIGNALS).replace('junction="-1"', f'junction="-1" rule="{rule}"')
    return document(road, header_extra=GEOREFERENCE)


# -- reading the export back -------------------------------------------------------------------------------------

class Lanelet2View:
    """A Lanelet2 map loaded at our origin, its lanelets by our LaneKey, and positions in our local frame."""

    def __init__(self, lanelet2, osm: Path, origin: tuple[float, float], odr, georeference=None):
        from lanelet2.io import Origin
        from lanelet2.projection import LocalCartesianProjector

        self.lanelet2 = lanelet2
        self.map, self.errors = lanelet2.io.loadRobust(str(osm), LocalCartesianProjector(Origin(*origin)))
        self.origin = origin
        self.odr = odr
        self.georeference = georeference or odr.georeference
        self.by_key = {}
        for ll in self.map.laneletLayer:
            attributes = ll.attributes
            key = LaneKey(odr.road_index[attributes["opendrive:road"]], int(attributes["opendrive:lane_section"]),
                          int(attributes["opendrive:lane"]))
            self.by_key[key] = ll
        self.key_of = {ll.id: key for key, ll in self.by_key.items()}
        traffic_rules = lanelet2.traffic_rules
        self.rules = traffic_rules.create(traffic_rules.Locations.Germany, traffic_rules.Participants.Vehicle)
        self.graph = lanelet2.routing.RoutingGraph(self.map, self.rules)

    @cached_property
    def _to_wgs84(self):
        """PROJ's topocentric conversion is GeographicLib's LocalCartesian, to nanometres (made once: a
        transformer costs milliseconds, a region has 160,000 lanelets)."""
        import pyproj

        lat0, lon0 = self.origin
        return pyproj.Transformer.from_pipeline(
            "+proj=pipeline +step +proj=axisswap +order=2,1 +step +proj=unitconvert +xy_in=deg +xy_out=rad "
            f"+step +proj=cart +ellps=WGS84 +step +proj=topocentric +ellps=WGS84 +lat_0={lat0!r} +lon_0={lon0!r} "
            "+h_0=0")

    def to_local(self, xyz: np.ndarray) -> np.ndarray:
        """Lanelet2's LocalCartesian (x, y) -> WGS84 -> our local (x, y), vectorised."""
        lat, lon, _ = self._to_wgs84.transform(xyz[:, 0], xyz[:, 1], xyz[:, 2], direction="INVERSE")
        x, y = self.georeference.wgs84_to_local(lon, lat)
        return np.column_stack([x, y])

    def edges(self, keys) -> set:
        """(from, to, kind) of Lanelet2's routing graph from the given lanes: follow, left, right."""
        found = set()
        for key in keys:
            ll = self.by_key.get(key)
            if ll is None:
                continue
            for following in self.graph.following(ll, False):
                found.add((key, self.key_of[following.id], "follow"))
            for kind, neighbour in (("left", self.graph.left(ll)), ("right", self.graph.right(ll))):
                if neighbour is not None:
                    found.add((key, self.key_of[neighbour.id], kind))
        return found

    @cached_property
    def _centre_line_owner(self) -> dict:
        return {ll.centerline.id: key for key, ll in self.by_key.items()}

    def sections_at(self, point) -> tuple[set, bool]:
        """(the lane sections (road, section) whose lanelet bounds or centre lines hold ``point``, whether
        one of them starts or ends there)."""
        sections, end = set(), False
        for way in self.map.lineStringLayer.findUsages(point):
            # a lanelet against the way's direction holds it inverted, and only that finds it
            owners = [self.key_of[ll.id] for line in (way, way.invert())
                      for ll in self.map.laneletLayer.findUsages(line)]
            owners += [self._centre_line_owner[way.id]] if way.id in self._centre_line_owner else []
            if not owners:
                continue  # a signal's way
            end |= point.id in (way[0].id, way[-1].id)
            sections |= {(key.road_index, key.section_index) for key in owners}
        return sections, end

    def inside_out(self) -> set:
        return {key for key, ll in self.by_key.items() if "opendrive:inside_out" in ll.attributes}


def _export(lanelet2, odr, tmp_path: Path, name: str, **options) -> tuple[Lanelet2View, dict]:
    osm = tmp_path / f"{name}.osm"
    started = time.perf_counter()
    summary = export_lanelet2(odr, str(osm), name=name, **options)
    summary["seconds"] = time.perf_counter() - started
    return Lanelet2View(lanelet2, osm, summary["origin"], odr), summary


def check_against_lanelet2(view: Lanelet2View, starts: int = 6) -> dict:
    """The issue's checks; returns the figures measured."""
    odr = view.odr
    # (a) loads without errors, and Lanelet2's own routing-graph validation has nothing to say
    assert view.errors == []
    assert view.graph.checkValidity() == []
    ours = LaneGraph.from_opendrive(odr, lane_types=VEHICLE_LANE_TYPE_NAMES)
    assert set(ours.keys) <= set(view.by_key), "every lane of our lane graph has a lanelet"
    # (b) the same successors and lane changes; lanelets whose own lane runs inside out carry private bounds,
    # so only their lane changes may be missing
    mine = set(ours.edge_list())
    theirs = view.edges(ours.keys)
    inside_out = view.inside_out()
    assert theirs <= mine, sorted(theirs - mine)[:5]
    missing = mine - theirs
    assert all(kind != "follow" and (a in inside_out or b in inside_out) for a, b, kind in missing), \
        sorted(missing)[:5]
    import networkx as nx

    reference = ours.to_networkx()
    keys = sorted(ours.keys)
    chosen = [keys[i] for i in np.linspace(0, len(keys) - 1, min(starts, len(keys))).astype(int)]
    for start in chosen:
        reached = {view.key_of[ll.id] for ll in view.graph.reachableSet(view.by_key[start], 1e12, 0, True)}
        assert reached == nx.descendants(reference, start) | {start}, start
    # (c) centre lines: Lanelet2's vertices lie on our centre, and our (finely sampled) centre on Lanelet2's --
    # but for lanes whose centre itself runs backwards somewhere (inside out: the exporter cuts the loop out)
    import shapely

    from tavf_mapkit.lanelet2_export.folds import backward_segments
    from tavf_mapkit.lanelet2_export.parts import sample_in_parts
    from tavf_mapkit.mesh.adaptive import adaptive_samples

    fine = adaptive_samples(odr, 0.002)
    lanelet_of_row = {ours.row(key): ll for key, ll in view.by_key.items() if key in ours}
    folded = set()
    to_ours, to_theirs, compared = [], [], 0
    # in parts of whole lane sections, as the export samples (a region's lanes at once exceed the map's budget)
    for sampling in sample_in_parts(odr, fine.section, fine.s):
        centre = sampling.center_points(with_height=False)[:, :2]
        heading = sampling.heading[sampling.pair_sample]
        backward = backward_segments(centre, np.column_stack([np.cos(heading), np.sin(heading)]),
                                     sampling.pair_lane[1:] == sampling.pair_lane[:-1], 1e-3)
        folded_here = set(sampling.pair_lane[:-1][backward].tolist())
        folded |= folded_here
        rows, starts = np.unique(sampling.pair_lane, return_index=True)  # pairs come lane by lane
        for row, start, end in zip(rows.tolist(), starts.tolist(), np.append(starts[1:], len(centre)).tolist()):
            ll = lanelet_of_row.get(row)
            if ll is None:
                continue
            our_line = centre[start:end]
            compared += 1
            their_line = view.to_local(np.array([[p.x, p.y, p.z] for p in ll.centerline]))
            to_ours.append(shapely.distance(shapely.points(their_line), shapely.LineString(our_line)))
            if row not in folded_here:
                to_theirs.append(shapely.distance(shapely.points(our_line), shapely.LineString(their_line)))
    assert compared == len(lanelet_of_row)
    to_ours, to_theirs = np.concatenate(to_ours), np.concatenate(to_theirs)
    assert to_ours.max() < CENTRE_TOLERANCE and to_theirs.max() < CENTRE_TOLERANCE
    # (d) neighbours in a lane section share one bound way; no two nodes within 1 mm but where a lane ends on
    # a point of a section no link joins it to (one two-way street's road starts on the centre line where the
    # other one ends, or passes by)
    shared = 0
    for key, ll in view.by_key.items():
        outward = key.lane_id + (1 if key.lane_id > 0 else -1)
        for neighbour_id in (outward,) + ((-1,) if key.lane_id == 1 else ()):
            other = view.by_key.get(LaneKey(key.road_index, key.section_index, neighbour_id))
            if other is None or key in inside_out or LaneKey(key.road_index, key.section_index,
                                                            neighbour_id) in inside_out:
                continue
            assert {ll.leftBound.id, ll.rightBound.id} & {other.leftBound.id, other.rightBound.id}, (key, other)
            shared += 1
    from scipy.spatial import cKDTree

    layer = view.map.pointLayer
    point_list = list(layer)
    points = np.fromiter((c for p in point_list for c in (p.x, p.y, p.z)), float, 3 * len(layer)).reshape(-1, 3)
    close = cKDTree(points).query_pairs(1e-3, output_type="ndarray")
    for i, j in close:
        (a, a_ends), (b, b_ends) = view.sections_at(point_list[i]), view.sections_at(point_list[j])
        assert (a_ends or b_ends) and not a & b, (a, a_ends, b, b_ends)
    return {"centre_max": float(max(to_ours.max(), to_theirs.max())),
            "centre_p99": float(np.percentile(np.concatenate([to_ours, to_theirs]), 99)),
            "shared_pairs": shared, "edges": len(mine), "missing_edges": len(missing),
            "touching_lane_ends": len(close),
            "folded_centres": len(folded & {ours.row(k) for k in ours.keys})}


# -- tests ------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("rule", ["RHT", "LHT"])
def test_synthetic_road(lanelet2, tmp_path, rule):
    xodr = tmp_path / "synthetic.xodr"
    xodr.write_text(synthetic_xodr(rule))
    osm = tmp_path / "synthetic.osm"
    result = CliRunner().invoke(cli, ["export", str(xodr), "--to", "lanelet2", "-o", str(osm)])
    assert result.exit_code == 0, result.output
    origin = tuple(float(v) for v in re.search(r"origin +lat (\S+) lon (\S+)", result.output).groups())
    assert origin == pytest.approx((53.55, 10.0), abs=1e-9)
    odr = load_opendrive(str(xodr))
    view = Lanelet2View(lanelet2, osm, origin, odr)
    check_against_lanelet2(view)
    ll = {(k.section_index, k.lane_id): v for k, v in view.by_key.items()}
    assert sorted(ll) == [(s, i) for s in (0, 1) for i in (-4, -3, -2, -1, 1, 2)]
    assert {i: ll[(0, i)].attributes["subtype"] for i in (-4, -3, -2, -1, 1, 2)} == {
        -4: "walkway", -3: "bicycle_lane", -2: "road", -1: "road", 1: "road", 2: "road"}

    # driving direction: right-hand traffic drives the right lanes with s (+x), left-hand the left ones
    for (section, lane_id), lanelet in ll.items():
        first, last = lanelet.centerline[0], lanelet.centerline[-1]
        with_s = (lane_id < 0) == (rule == "RHT")
        assert (last.x - first.x > 49.0) if with_s else (first.x - last.x > 49.0), (section, lane_id)
    # the centre line is the left bound of both directions' inner lanes in RHT, the right bound in LHT
    side = "leftBound" if rule == "RHT" else "rightBound"
    assert getattr(ll[(0, 1)], side).id == getattr(ll[(0, -1)], side).id
    # neighbours share one way; the sections share their end points
    assert ll[(0, -1)].rightBound.id == ll[(0, -2)].leftBound.id if rule == "RHT" else \
        ll[(0, -1)].leftBound.id == ll[(0, -2)].rightBound.id
    first, second = (ll[(0, -1)], ll[(1, -1)]) if rule == "RHT" else (ll[(1, -1)], ll[(0, -1)])
    assert first.leftBound[-1].id == second.leftBound[0].id and first.rightBound[-1].id == second.rightBound[0].id

    # road marks as line types: broken then solid between -1 and -2, solid_solid in the middle, the raised
    # sidewalk behind curbstones, "solid broken" on lane 1 as dashed_solid along s (crossable from lane 2 only)
    def tags(way):
        attributes = dict(way.attributes)
        return attributes["type"], attributes.get("subtype")

    def border(section, inner, outer):
        a, b = ll[(section, inner)], ll[(section, outer)]
        common = {a.leftBound.id, a.rightBound.id} & {b.leftBound.id, b.rightBound.id}
        (way_id,) = common
        return view.map.lineStringLayer[way_id]

    assert tags(border(0, -1, -2)) == ("line_thin", "dashed")
    assert tags(border(1, -1, -2)) == ("line_thin", "solid")
    assert tags(border(0, 1, -1)) == ("line_thin", "solid_solid")
    assert tags(border(0, -3, -4)) == ("curbstone", "high")
    assert tags(border(0, 1, 2)) == ("line_thin", "dashed_solid")
    graph = view.graph

    def changes(section, lane_id):
        lanelet = ll[(section, lane_id)]
        return {view.key_of[n.id].lane_id for n in (graph.left(lanelet), graph.right(lanelet)) if n is not None}

    assert changes(0, -1) == {-2} and changes(0, -2) == {-1}
    assert changes(1, -1) == set() and changes(1, -2) == set()
    assert changes(0, 2) == {1} and changes(0, 1) == set()
    assert not view.rules.canPass(ll[(0, -3)]) and not view.rules.canPass(ll[(0, -4)])

    # speed: the lane's record, else the road type's (km/h)
    assert view.rules.speedLimit(ll[(0, -1)]).speedLimit == pytest.approx(50.0)
    assert view.rules.speedLimit(ll[(0, -2)]).speedLimit == pytest.approx(30.0)

    # signals: the light over -1 and -2 (its validity) at s=95, t=-4 +- 0.15, 4.5 m up, its stop line across
    # both lanes; the stop sign (orientation "-") on the lanes that drive against s
    light = ll[(1, -1)].trafficLights()
    assert len(light) == 1 and light[0] in ll[(1, -2)].regulatoryElements
    corners = np.array([[p.x, p.y, p.z] for ls in light[0].trafficLights for p in ls])
    assert view.to_local(corners) == pytest.approx(np.array([[95.0, -4.15], [95.0, -3.85]]), abs=2e-3)
    assert corners[:, 2] == pytest.approx(4.5, abs=2e-3)
    assert light[0].trafficLights[0].attributes["type"] == "traffic_light"
    stop_line = view.to_local(np.array([[p.x, p.y, p.z] for p in light[0].stopLine]))
    assert stop_line[:, 0] == pytest.approx(95.0, abs=2e-3)
    assert sorted(stop_line[:, 1]) == pytest.approx([-6.5, -3.25, 0.0], abs=2e-3)
    against_s = (1, 2) if rule == "RHT" else (-1, -2, -3, -4)
    signs = {i: [r for r in ll[(0, i)].regulatoryElements if r.attributes["subtype"] == "traffic_sign"]
             for i in (-4, -3, -2, -1, 1, 2)}
    assert {i for i, found in signs.items() if found} == set(against_s)
    assert signs[against_s[0]][0].parameters["refers"][0].attributes["subtype"] == "de206"

    # every node where our georeference puts it: the lane borders of a straight road along x
    border_y = view.to_local(np.array([[p.x, p.y, p.z] for p in border(0, -1, -2)]))[:, 1]
    assert border_y == pytest.approx(-3.25, abs=1e-3)


def _end_to_end_roads(linked: bool) -> str:
    """Roads 1 and 2 along x, 2 starting where 1 ends, each with lanes 1, -1, -2 (driving; widths equal, so
    every lane end of road 1 touches one of road 2). Linked: the roads, lanes -1 and 1, not lane -2."""
    def lanes(own: str) -> str:
        link = (lambda lane_id: f'<link><{own} id="{lane_id}"/></link>') if linked else (lambda lane_id: "")
        return f"""<laneSection s="0">
          <left>{_lane(1, "driving", 3.5).replace('level="false">', 'level="false">' + link(1))}</left>
          <center><lane id="0" type="none" level="false"/></center>
          <right>{_lane(-1, "driving", 3.25).replace('level="false">', 'level="false">' + link(-1))}
                 {_lane(-2, "driving", 3.25)}</right>
        </laneSection>"""

    def road_link(kind: str, other: str, contact: str) -> str:
        return f'<link><{kind} elementType="road" elementId="{other}" contactPoint="{contact}"/></link>' \
            if linked else ""

    first = road_xml('<geometry s="0" x="0" y="0" hdg="0" length="50"><line/></geometry>', 50.0,
                     lanes=lanes("successor"), road_id="1", link=road_link("successor", "2", "start"))
    second = road_xml('<geometry s="0" x="50" y="0" hdg="0" length="50"><line/></geometry>', 50.0,
                      lanes=lanes("predecessor"), road_id="2", link=road_link("predecessor", "1", "end"))
    return document(first, second, header_extra=GEOREFERENCE)


@pytest.mark.parametrize("linked", [False, True])
def test_touching_lane_ends_follow_only_where_linked(lanelet2, tmp_path, linked):
    """Lanelet2 reads a successor wherever a lanelet starts on the nodes another one ends on, so lane ends
    that only touch must not share nodes (Columbus: two such edges among 155,528 roads): road 2 follows
    road 1 in Lanelet2 exactly where the links say so, and the unlinked ends keep nodes of their own."""
    xodr = tmp_path / "roads.xodr"
    xodr.write_text(_end_to_end_roads(linked))
    odr = load_opendrive(str(xodr))
    view, _ = _export(lanelet2, odr, tmp_path, "roads")
    check_against_lanelet2(view)
    follows = {(a.road_index, a.lane_id, b.road_index, b.lane_id)
               for a, b, kind in view.edges(view.by_key) if kind == "follow"}
    assert follows == ({(0, -1, 1, -1), (1, 1, 0, 1)} if linked else set())
    lane = {(key.road_index, key.lane_id): ll for key, ll in view.by_key.items()}
    # the end of road 1's lane -2 and the start of road 2's: the same place, two nodes (one where linked)
    end, start = lane[(0, -2)].rightBound[-1], lane[(1, -2)].rightBound[0]
    assert end.id != start.id and np.hypot(end.x - start.x, end.y - start.y) < 1e-6
    shared = lane[(0, -1)].rightBound[-1].id == lane[(1, -1)].rightBound[0].id
    assert shared == linked


def test_sample_build(lanelet2, sample_build_dir, tmp_path):
    odr = load_opendrive(sample_build_dir / "sample.xodr")
    view, summary = _export(lanelet2, odr, tmp_path, "sample")
    figures = check_against_lanelet2(view)
    assert summary["lanelets"] == len(view.by_key) == len(odr.arrays.lane_id)  # every lane is a driving lane
    assert summary["regulatory_elements"] == sum(len(road.signals) for road in odr.roads) == 14
    assert summary["turned"] == 0 and summary["unjoined_lane_ends"] == 0
    assert figures["shared_pairs"] > 0


def test_left_hand_traffic_zoo_road(lanelet2, shared, tmp_path):
    """esmini's left-hand-traffic road (rule="LHT", no georeference: placed with --origin)."""
    xodr = shared(*ESMINI_LHT)
    odr = load_opendrive(str(xodr))
    assert {road.rule for road in odr.roads} == {"LHT"}
    osm = tmp_path / "lht.osm"
    result = CliRunner().invoke(cli, ["export", str(xodr), "--to", "lanelet2", "-o", str(osm)])
    assert result.exit_code == 2 and "has no <geoReference>: give --origin LAT,LON" in result.output
    result = CliRunner().invoke(cli, ["export", str(xodr), "--to", "lanelet2", "--origin", "51.5074,-0.1278",
                                      "-o", str(osm)])
    assert result.exit_code == 0, result.output
    from tavf_mapkit.lanelet2_export import map_georeference

    view = Lanelet2View(lanelet2, osm, (51.5074, -0.1278), odr, map_georeference(odr, (51.5074, -0.1278)))
    check_against_lanelet2(view)
    road = odr.roads[0]
    driving = [key for key in view.by_key if road.lane_sections[key.section_index].by_id[key.lane_id].type
               == "driving"]
    assert len(driving) == 6
    for key in driving:
        centre = view.to_local(np.array([[p.x, p.y, p.z] for p in view.by_key[key].centerline]))
        section = road.lane_sections[key.section_index]
        s = 0.5 * (section.s0 + road.section_end(key.section_index))
        *_, heading, _, _ = road.reference_point([s])
        step = centre[len(centre) // 2 + 1] - centre[len(centre) // 2]
        along = step @ np.array([np.cos(heading[0]), np.sin(heading[0])])
        # left-hand traffic: lanes left of the reference line (ids > 0) run with s
        assert (along > 0) == (key.lane_id > 0), key


def test_names_from_the_file_are_escaped(lanelet2, tmp_path):
    """Road and signal ids come from the input: quotes, ampersands and angle brackets reach Lanelet2 intact."""
    xodr = tmp_path / "names.xodr"
    text = synthetic_xodr().replace('<road id="1"', '<road id="A&amp;B &quot;1&quot; &lt;x&gt;"')
    xodr.write_text(text.replace('id="stop1"', 'id="stop&amp;go"'))
    odr = load_opendrive(str(xodr))
    view, _ = _export(lanelet2, odr, tmp_path, "names")
    assert view.errors == []
    assert {ll.attributes["opendrive:road"] for ll in view.by_key.values()} == {'A&B "1" <x>'}
    signs = [r for r in view.map.regulatoryElementLayer if r.attributes["subtype"] == "traffic_sign"]
    assert signs[0].parameters["refers"][0].attributes["opendrive:signal"] == "stop&go"


def test_parts_make_the_same_map(sample_build_dir):
    """A region is sampled in parts of whole lane sections (lanelet2_export/parts.py: Columbus's 4.25 million
    lane samples at once would exceed the map's budget of one allocation); the file must not depend on where
    the parts end."""
    from tavf_mapkit.lanelet2_export import build_lanelet_map
    from tavf_mapkit.lanelet2_export.osmxml import osm_text
    from tavf_mapkit.lanelet2_export.parts import section_runs
    from tavf_mapkit.mesh.adaptive import adaptive_samples

    odr = load_opendrive(sample_build_dir / "sample.xodr")
    arrays = odr.arrays
    samples = adaptive_samples(odr, 0.01)
    lanes = np.bincount(arrays.lane_section, minlength=len(arrays.section_s0))
    for part_pairs in (1, 700, 10**9):
        runs = section_runs(arrays, samples.section, part_pairs)
        # the runs cover the samples in order, each of whole sections, none much bigger than asked
        assert runs[0].start == 0 and runs[-1].stop == len(samples.section)
        assert all(a.stop == b.start for a, b in itertools.pairwise(runs))
        assert all(samples.section[r.start - 1] != samples.section[r.start] for r in runs[1:])
        for run in runs:
            pairs = lanes[samples.section[run]]
            last = samples.section[run.stop - 1]
            assert pairs.sum() < part_pairs + pairs[samples.section[run] == last].sum()
        assert (len(runs) > 1) == (part_pairs < 10**9)
    assert len(section_runs(arrays, samples.section, 1)) == len(np.unique(samples.section))

    def text(laneletmap):
        return osm_text(laneletmap, laneletmap.nodes[:, 0], laneletmap.nodes[:, 1])

    whole = text(build_lanelet_map(odr, part_pairs=10**9))
    assert text(build_lanelet_map(odr, part_pairs=700)) == whole
    assert text(build_lanelet_map(odr, step=0.5, part_pairs=10**9)) == text(build_lanelet_map(odr, step=0.5,
                                                                                              part_pairs=1))


def test_file_written_in_blocks(tmp_path, monkeypatch):
    """Nodes and ways are formatted a block at a time (a region's file is gigabytes): ids and references run
    on across blocks, so any block size gives the same file."""
    from tavf_mapkit.lanelet2_export import build_lanelet_map, osmxml

    xodr = tmp_path / "synthetic.xodr"
    xodr.write_text(synthetic_xodr())
    laneletmap = build_lanelet_map(load_opendrive(str(xodr)))
    lon, lat = laneletmap.nodes[:, 0] * 1e-5, laneletmap.nodes[:, 1] * 1e-5
    whole = osmxml.osm_text(laneletmap, lon, lat, "c")
    assert len(laneletmap.nodes) > 7 and len(laneletmap.way_nodes) > 7
    monkeypatch.setattr(osmxml, "_BLOCK", 7)
    assert len(list(osmxml.osm_chunks(laneletmap, lon, lat, "c"))) > 4
    assert osmxml.osm_text(laneletmap, lon, lat, "c") == whole


def test_merged_nodes_numbered_by_first_point():
    """Points closer than NODE_RADIUS and joined points become one node at their mean; nodes are numbered in
    the order of their first point (the file must not depend on scipy's component numbering)."""
    from tavf_mapkit.lanelet2_export.nodes import NODE_RADIUS, merge_points

    rng = np.random.default_rng(5)
    base = rng.uniform(0, 100, (300, 3))
    points = np.concatenate([base, base[::-1] + 0.2 * NODE_RADIUS, base[:10] + 1.0])  # copies, then far ones
    node_of, positions = merge_points(points, np.array([[0, 300 + 300 + 9]]))  # point 0 joined to base[9] + 1
    _, first = np.unique(node_of, return_index=True)
    assert np.array_equal(node_of[np.sort(first)], np.arange(len(positions)))
    assert len(positions) == 300 + 9 and node_of[609] == node_of[0]
    assert np.array_equal(node_of[300:600], node_of[:300][::-1])
    assert positions[node_of[1]] == pytest.approx(base[1] + 0.1 * NODE_RADIUS)


def test_merged_nodes_only_within_a_group():
    """Coinciding points of two groups (two lane sections' lane ends) stay two nodes unless joined; a free
    point (signal geometry) takes the nearest node and never bridges two groups; a node made of several
    groups (joined lane ends) still takes a point of any of them that lies within the radius; nodes of
    shared points only (no lane end) merge across groups."""
    from tavf_mapkit.lanelet2_export.nodes import FREE, NODE_RADIUS, merge_points

    r = NODE_RADIUS
    points = np.array([[0, 0, 0], [0.2 * r, 0, 0],          # 0, 1: groups 0 and 1 at one place
                       [10, 0, 0], [10 + 0.1 * r, 0, 0],    # 2, 3: groups 0 and 1, joined
                       [10, 0.6 * r, 0],                    # 4: group 1 beside the joined node
                       [0.1 * r, 0, 0],                     # 5: free, between 0 and 1
                       [20, 0, 0], [20 + 0.5 * r, 0, 0],    # 6, 7: free, alone
                       [30, 0, 0], [30, 0.5 * r, 0],        # 8, 9: shared, groups 0 and 1
                       [40, 0, 0], [40, 0.5 * r, 0], [40, r, 0]], dtype=float)  # 10-12: shared 0, 1, not 1
    group = np.array([0, 1, 0, 1, 1, FREE, FREE, FREE, 0, 1, 0, 1, 1])
    shared = np.zeros(len(points), dtype=bool)
    shared[[8, 9, 10, 11]] = True
    node_of, positions = merge_points(points, np.array([[2, 3]]), group, shared)
    assert node_of[0] != node_of[1] and node_of[5] in (node_of[0], node_of[1])
    assert node_of[2] == node_of[3] == node_of[4]
    assert node_of[6] == node_of[7]
    assert node_of[8] == node_of[9]  # no lane end there: one node across sections
    # 11 takes 12 (one section), so that node holds a lane end and stays apart from 10 (another section)
    assert node_of[11] == node_of[12] != node_of[10] and len(positions) == 7
    # without groups every coinciding point is one node, as before
    node_of, _ = merge_points(points, np.array([[2, 3]]))
    assert node_of[0] == node_of[1] == node_of[5]


def test_runs_of_sections():
    """untangle's members per suspect section by one stable sort: what a mask per section gives."""
    from tavf_mapkit.lanelet2_export.untangle import _runs_of

    key = np.random.default_rng(3).integers(-1, 40, 2000)
    wanted = np.array([0, 3, 17, 39, 45])
    for value, run in zip(wanted, _runs_of(key, wanted)):
        assert run.tolist() == np.flatnonzero(key == value).tolist()


def test_private_bounds_of_several_lanelets():
    """Lanelets the loader would turn get bounds of their own through a cross-section; their new nodes are
    numbered on from the map's, lanelet after lanelet, and joined to the map's nodes once at the end: the
    bounds as written (final node numbers) pass the loader's test."""
    from tavf_mapkit.lanelet2_export.laneletmap import LaneletMap
    from tavf_mapkit.lanelet2_export.orientation import give_private_bounds, turned_lanelets

    # three straight lanes along x, 3 m wide, 10 m apart; each lists its bounds swapped (left on the right)
    nodes, way_nodes, lanelets = [], [], []
    for k, forward in enumerate((True, False, True)):
        y = 10.0 * k
        for side in (-1.5, 1.5):
            way_nodes.append(np.arange(len(nodes), len(nodes) + 3))
            nodes += [[x, y + side, 0.0] for x in (0.0, 5.0, 10.0)]
        lower, upper = len(way_nodes) - 2, len(way_nodes) - 1
        # driving +x the left bound is the upper one, driving -x the lower one: list the other
        lanelets.append({"left": lower if forward else upper, "right": upper if forward else lower,
                         "forward": forward, "heading": 0.0 if forward else np.pi,
                         "middle": np.array([5.0, y, 0.0]), "tags": {}, "regulatory": []})
    laneletmap = LaneletMap(np.array(nodes), way_nodes, [{"type": "virtual"} for _ in way_nodes], lanelets)
    assert turned_lanelets(laneletmap) == [0, 1, 2]
    assert give_private_bounds(laneletmap) == (3, 0)
    assert turned_lanelets(laneletmap) == []
    assert len(laneletmap.nodes) > len(nodes) and np.array_equal(laneletmap.nodes[:len(nodes)], nodes)
    used = np.concatenate([laneletmap.way_nodes[ll[side]] for ll in lanelets for side in ("left", "right")])
    assert set(range(len(nodes), len(laneletmap.nodes))) <= set(used.tolist())  # every new node in a bound
    assert all(ll["tags"] == {"opendrive:inside_out": "yes"} for ll in lanelets)


def test_private_bounds_of_an_inside_out_u_turn():
    """Columbus's last turned lanelet (road 187692, a 4.3 m single-lane U-turn in junction 1652, its bounds
    thinned): the lane is wider than the turn's radius, so its inner bound folds back on itself and its outer
    one sweeps round the other side; in its middle the lane's own direction points back (-x) while it drives
    from its start (heading -y) to its end (+y) along +x. Only a cross-section square to that chord passes
    the loader's test."""
    from tavf_mapkit.lanelet2_export.laneletmap import LaneletMap
    from tavf_mapkit.lanelet2_export.orientation import give_private_bounds, turned_lanelets

    left = [[0.0, 0.0], [-0.29, -1.65], [-0.34, -1.84], [-0.36, -1.88], [-0.38, -1.89], [-0.4, -1.87],
            [-0.41, -1.83], [-0.42, -1.63], [-0.36, 0.44]]
    right = [[-3.96, 0.59], [-4.18, -0.72], [-4.05, -0.34], [-3.66, 0.37], [-2.81, 1.28], [-1.49, 1.95],
             [0.94, 1.88], [2.43, 0.95], [3.15, -0.02], [3.49, -0.91], [3.57, -1.43], [3.59, -0.78], [3.63, 0.23]]
    nodes = np.column_stack([np.array(left + right), np.zeros(len(left) + len(right))])
    lanelet = {"left": 0, "right": 1, "forward": True, "heading": 3.0169, "middle": np.array([-0.13, 0.09, 0.0]),
               "tags": {}, "regulatory": []}
    laneletmap = LaneletMap(nodes, [np.arange(len(left)), np.arange(len(left), len(nodes))],
                            [{"type": "virtual"}] * 2, [lanelet])
    assert turned_lanelets(laneletmap) == [0]
    assert give_private_bounds(laneletmap) == (1, 0)
    assert turned_lanelets(laneletmap) == []
    left_bound = laneletmap.nodes[laneletmap.way_nodes[lanelet["left"]]]
    right_bound = laneletmap.nodes[laneletmap.way_nodes[lanelet["right"]]]
    # the corners stay (successors), the cross-section runs along +x with the left bound on +y
    assert np.array_equal(left_bound[[0, -1]], nodes[[0, len(left) - 1]])
    assert np.array_equal(right_bound[[0, -1]], nodes[[len(left), len(nodes) - 1]])
    assert left_bound[2, 0] > left_bound[1, 0] and left_bound[2, 1] > right_bound[2, 1]


def test_cli_errors(tmp_path, lanelet2):
    xodr = tmp_path / "synthetic.xodr"
    xodr.write_text(synthetic_xodr())
    runner = CliRunner()
    for arguments, message in (
        (["--to", "lanelet2", "--format", "csv"],
         "Error: --format is for --layer; --to lanelet2 writes its own format"),
        ([], "Error: give either --layer LAYER or --to lanelet2"),
        (["--layer", "lane", "--to", "lanelet2"], "Error: give either --layer LAYER or --to lanelet2"),
        (["--layer", "lane", "--eps", "0.1"], "Error: --eps is for --to lanelet2"),
        (["--to", "lanelet2", "--origin", "53.5,10"],
         f"Error: {xodr}: has a <geoReference>; --origin is only for maps without one"),
    ):
        result = runner.invoke(cli, ["export", str(xodr), *arguments, "-o", str(tmp_path / "x.osm")])
        assert result.exit_code == 2 and result.output.strip().splitlines()[-1] == message, result.output
    result = runner.invoke(cli, ["export", str(tmp_path / "missing.xodr"), "--to", "lanelet2", "-o",
                                 str(tmp_path / "x.osm")])
    assert result.exit_code == 2 and result.output.strip() == f"Error: {tmp_path / 'missing.xodr'}: file not found"
    # a failed export leaves an existing output as it was
    target = tmp_path / "kept.osm"
    target.write_text("old")
    result = runner.invoke(cli, ["export", str(tmp_path / "missing.xodr"), "--to", "lanelet2", "-o", str(target)])
    assert result.exit_code == 2 and target.read_text() == "old"
    assert not list(tmp_path.glob(".kept.osm.*"))


@pytest.mark.slow
@pytest.mark.parametrize("fixture", ["tavf_dlr_build", "jungfernstieg_build"])
def test_real_build(lanelet2, fixture, request, tmp_path):
    folder = request.getfixturevalue(fixture)
    odr = load_opendrive(folder / f"{folder.name}.xodr")
    view, summary = _export(lanelet2, odr, tmp_path, folder.name)
    figures = check_against_lanelet2(view, starts=8)
    assert summary["turned"] == 0 and summary["unjoined_lane_ends"] == 0
    if fixture == "tavf_dlr_build":
        assert summary["regulatory_elements"] > 400  # DLR's network has its traffic lights
        assert any(ll.trafficLights() for ll in view.by_key.values())
    print(f"{folder.name}: {summary['lanelets']} lanelets, {summary['nodes']} nodes, export "
          f"{summary['seconds']:.2f} s, centre max {figures['centre_max'] * 1000:.1f} mm p99 "
          f"{figures['centre_p99'] * 1000:.2f} mm, {figures['missing_edges']} of {figures['edges']} lane-graph "
          f"edges missing (inside-out lanes: {summary['private_bounds']})")


def _loader_inversions(lanelet2, lefts: list[np.ndarray], rights: list[np.ndarray], tmp_path: Path):
    """(left inverted, right inverted) of each (left, right) pair of (n, 3) local bounds, as the real Lanelet2
    loader decides: the bounds written as one lanelet each (nodes as the export writes them), loaded at the
    origin with its LocalCartesian projector, and each loaded bound's first node compared with its way's."""
    import pyproj
    from lanelet2.io import Origin
    from lanelet2.projection import LocalCartesianProjector

    from tavf_mapkit.lanelet2_export.laneletmap import LaneletMap
    from tavf_mapkit.lanelet2_export.osmxml import osm_text

    origin = (53.55, 10.0)
    nodes, way_nodes, lanelets = [], [], []
    for left, right in zip(lefts, rights):
        for line in (left, right):
            way_nodes.append(np.arange(len(nodes), len(nodes) + len(line)))
            nodes.extend(line.tolist())
        lanelets.append({"left": len(way_nodes) - 2, "right": len(way_nodes) - 1, "tags": {
            "type": "lanelet", "subtype": "road", "location": "urban", "one_way": "yes"}, "regulatory": []})
    laneletmap = LaneletMap(np.array(nodes), way_nodes, [{"type": "line_thin", "subtype": "solid"}] * len(way_nodes),
                            lanelets)
    to_wgs84 = pyproj.Transformer.from_pipeline(
        "+proj=pipeline +step +proj=axisswap +order=2,1 +step +proj=unitconvert +xy_in=deg +xy_out=rad "
        f"+step +proj=cart +ellps=WGS84 +step +proj=topocentric +ellps=WGS84 +lat_0={origin[0]} "
        f"+lon_0={origin[1]} +h_0=0")
    xyz = laneletmap.nodes
    lat, lon, _ = to_wgs84.transform(xyz[:, 0], xyz[:, 1], xyz[:, 2], direction="INVERSE")
    osm = tmp_path / "orientation.osm"
    osm.write_text(osm_text(laneletmap, lon, lat))
    loaded = lanelet2.io.load(str(osm), LocalCartesianProjector(Origin(*origin)))
    first_lanelet = len(nodes) + len(way_nodes) + 1  # osmxml's ids: nodes, ways, then lanelets
    result = []
    for i, (left_way, right_way) in enumerate(zip(way_nodes[::2], way_nodes[1::2])):
        lanelet = loaded.laneletLayer[first_lanelet + i]
        result.append((lanelet.leftBound[0].id != left_way[0] + 1, lanelet.rightBound[0].id != right_way[0] + 1))
    return result


def _curl_bound() -> np.ndarray:
    """Columbus ramp 151076's left bound (m from its last turn, as exported, the straight before the curl
    thinned): the folded inner border leaves a curl that runs 36 cm back (+y) against the lane (-y) before a
    38 m straight."""
    curl = [[0.261, -0.36], [0.233, -0.349], [0.206, -0.336], [0.179, -0.322], [0.154, -0.306], [0.129, -0.289],
            [0.106, -0.27], [0.084, -0.249], [0.064, -0.226], [0.047, -0.202], [0.032, -0.176], [0.02, -0.148],
            [0.01, -0.119], [0.004, -0.09], [0.0, -0.06], [-0.001, -0.03], [0.0, 0.0]]
    xy = [[21.546, 48.563], [16.85, 5.94], [11.84, 0.52], [5.0, -0.3], *curl, [-2.702, -38.234], [-5.403, -76.468],
          [-8.105, -114.702]]
    return np.column_stack([np.array(xy), np.zeros(len(xy))])


def _random_bounds(rng, count: int) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """``count`` random (left, right) pairs: along +x, the right one at -width, each with its own wiggle (none
    to 5 m), some with their points out of order (running back on themselves), some at other heights; turned
    to a random heading."""
    lefts, rights = [], []
    for _ in range(count):
        n_left, n_right = rng.integers(2, 12, 2)
        length = rng.uniform(0.05, 60.0)
        width = rng.uniform(0.0, 6.0)
        angle = rng.uniform(0, 2 * np.pi)
        turn = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]])
        pair = []
        for n, y0 in ((n_left, 0.0), (n_right, -width)):
            s = np.sort(rng.uniform(0, length, n)) if rng.random() < 0.7 else rng.uniform(0, length, n)
            y = y0 + rng.normal(0, rng.choice([0.0, 0.01, 0.5, 5.0]), n)
            z = rng.normal(0, rng.choice([0.0, 2.0]), n)
            pair.append(np.column_stack([s, y, z]) @ turn.T)
        lefts.append(pair[0])
        rights.append(pair[1])
    return lefts, rights


def test_orientation_replica_agrees_with_the_lanelet2_loader(lanelet2, tmp_path):
    """``orientation``'s replica of Lanelet2's ``align`` against the real loader on 400 random lanelets (smooth
    curves, zigzags, folds, curls, one-segment bounds, bounds with points at other heights) plus the two kinds
    of Columbus lanelet it misread: where the replica says it knows, it must say what the loader does; where
    the loader's answer hangs on a tie it must say it does not know (those lanelets get other bounds)."""
    from tavf_mapkit.lanelet2_export.orientation import inverted_bounds

    lefts, rights = _random_bounds(np.random.default_rng(11), 400)
    # Columbus 151076: the right bound's middle point nearest the curl's tip, where the segments disagree
    curl = _curl_bound()
    lefts.append(curl)
    rights.append(np.array([[17.57, 49.001, 0.0], [1.193, 3.519, 0.0], [-12.095, -114.42, 0.0]]))
    # Columbus U-turn 251407 cut to its corners: the right chord's middle point on the inner bound's line
    lefts.append(np.array([[0.0, 0.0, 0.0], [0.077, 0.016, 0.0]]))
    rights.append(np.array([[0.0385 + 4 * 0.016, 0.008 - 4 * 0.077, 0.0], [0.0385 - 4 * 0.016, 0.008 + 4 * 0.077, 0.0]]))
    loader = _loader_inversions(lanelet2, lefts, rights, tmp_path)
    replica = [inverted_bounds(left, right) for left, right in zip(lefts, rights)]
    known = [i for i, r in enumerate(replica) if r is not None]
    wrong = [(i, replica[i], loader[i]) for i in known if replica[i] != loader[i]]
    assert not wrong, wrong
    assert len(known) >= 350, "the replica knows the loader's answer on almost every lanelet"
    assert replica[-2] is None and replica[-1] is None
