"""Scene solids (curbs, objects, signals, buildings): every one a closed manifold, placed where OpenDRIVE / OSM say."""

from __future__ import annotations

import math

import manifold3d
import numpy as np
import pytest
import trimesh

from tavf_mapkit.errors import InputError
from tavf_mapkit.mesh import road_surface
from tavf_mapkit.mesh.labelled import KIND_CODE
from tavf_mapkit.mesh.solid_buildings import parse_length, read_footprints, vertical_extent
from tavf_mapkit.mesh.solids import scene_solid_parts, scene_solids
from tavf_mapkit.opendrive import load_opendrive
from tavf_mapkit.xmlsafe import parse_safe, read_xml_source
from tests.conftest import shared_path
from tests.xodr_factory import document, road_xml


def assert_all_manifold(parts):
    """Independent of how a solid was built: manifold3d accepts it again and trimesh finds it watertight."""
    assert parts.solids
    for solid in parts.solids:
        mesh = solid.mesh
        again = manifold3d.Manifold(manifold3d.Mesh64(np.ascontiguousarray(mesh.vertices),
                                                      np.ascontiguousarray(mesh.faces, dtype=np.uint64)))
        assert again.status() == manifold3d.Error.NoError, solid.source
        shape = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
        assert shape.is_watertight and shape.is_winding_consistent, solid.source
        assert shape.volume > 0, solid.source  # outward normals
        assert np.all(mesh.kind == KIND_CODE[solid.kind])


_ESMINI: dict = {}


@pytest.fixture
def esmini():
    """(odr, road surface at eps 0.05) of an esmini sample, made once per session."""
    def load(name):
        if name not in _ESMINI:
            odr = load_opendrive(shared_path("xodr", "esmini", name))
            _ESMINI[name] = (odr, road_surface(odr, 0.05))
        return _ESMINI[name]
    return load


@pytest.mark.parametrize("name, kinds", [
    ("crest-curve.xodr", {"object"}),
    ("straight_500m_signs.xodr", {"object", "signal"}),
    ("fabriksgatan.xodr", {"curb"}),
    ("multi_intersections.xodr", {"curb", "signal"}),
])
def test_esmini_solids_are_manifold(esmini, name, kinds):
    odr, surface = esmini(name)
    parts = scene_solid_parts(odr, surface)
    assert_all_manifold(parts)
    assert {solid.kind for solid in parts.solids} == kinds


def test_box_and_cylinder_objects_have_their_size(esmini):
    odr, surface = esmini("crest-curve.xodr")
    parts = scene_solid_parts(odr, surface)
    box = next(s for s in parts.solids if s.source == "road 0 object 1")  # 5 x 1 x 1 m, hdg 1.57
    shape = box.mesh.to_trimesh()
    assert shape.volume == pytest.approx(5.0, rel=1e-9)
    road = odr.roads[0]
    base = road.surface_point(190.0, 7.5)[0]
    assert shape.bounds[0][2] == pytest.approx(base[2], abs=1e-9)
    assert shape.bounds[1][2] == pytest.approx(base[2] + 1.0, abs=1e-9)
    assert np.allclose(shape.vertices[:, :2].mean(axis=0), base[:2], atol=1e-9)
    # the object is turned by road heading + hdg: its 5 m side points that way
    heading = float(road.reference_point(190.0)[3][0]) + 1.57
    extent_along = np.ptp(shape.vertices[:, :2] @ np.array([math.cos(heading), math.sin(heading)]))
    assert extent_along == pytest.approx(5.0, abs=1e-9)
    # objects that only name an external model get no solid, and say so
    assert any(line.startswith("road 0 object 7:") for line in parts.skipped)


def test_cylinder_object_and_repeats(esmini):
    odr, surface = esmini("straight_500m_signs.xodr")
    parts = scene_solid_parts(odr, surface)
    pole = next(s for s in parts.solids if s.source == "road 1 object 1")  # radius 0.03, height 2.35
    shape = pole.mesh.to_trimesh()
    # a regular polygon inscribed in the circle: corners on the radius, sides within eps of it
    radial = np.hypot(*(shape.vertices[:, :2] - shape.vertices[:, :2].mean(axis=0)).T)
    assert np.allclose(radial, 0.03, atol=1e-9)
    sides = len(shape.vertices) // 2
    assert 0.03 * (1 - math.cos(math.pi / sides)) <= 0.05
    assert shape.volume == pytest.approx(sides / 2 * 0.03 ** 2 * math.sin(2 * math.pi / sides) * 2.35, rel=1e-9)
    assert np.ptp(shape.vertices[:, 2]) == pytest.approx(2.35, abs=1e-9)
    odr, surface = esmini("e6mini.xodr")
    parts = scene_solid_parts(odr, surface)
    # object 2: a rail pole every 4 m from s=0.1 over 1464.43 m -> 367 instances
    assert sum(1 for s in parts.solids if s.source.startswith("road 0 object 2 repeat 0 #")) == 367
    railing = next(s for s in parts.solids if s.source == "road 0 object 4 repeat 0")  # continuous, 0.35..0.55 m
    bottom, top = railing.mesh.vertices[:, 2].min(), railing.mesh.vertices[:, 2].max()
    road = odr.roads[0]
    z_road = road.surface_point(np.linspace(2.0, road.length, 20000), 1.35)[:, 2]
    assert bottom == pytest.approx(z_road.min() + 0.35, abs=0.01)
    assert top == pytest.approx(z_road.max() + 0.55, abs=0.01)


def test_curbs_close_the_raised_sidewalks(esmini):
    odr, surface = esmini("fabriksgatan.xodr")
    curbs = [s for s in scene_solid_parts(odr, surface).solids if s.kind == "curb"]
    assert curbs
    raised_vertices = set()
    for solid in curbs:
        z = solid.mesh.vertices[:, 2]
        assert np.ptp(z) >= 0.2  # reaches below the road level
        raised_vertices.update(map(tuple, np.round(solid.mesh.vertices, 9)))
    # every vertex of the surface's raised sidewalk faces is a vertex of a curb solid (they share the top)
    sidewalk = surface.select(surface.kind == KIND_CODE["sidewalk"])
    lane_height = np.array([max((h.inner for h in _lane(odr, r, lane).heights), default=0.0)
                            for r, lane in zip(sidewalk.road_index, sidewalk.lane_id)])
    top = sidewalk.select(lane_height > 0)
    assert len(top.faces)
    assert set(map(tuple, np.round(top.vertices, 9))) <= raised_vertices


def _lane(odr, road_index, lane_id):
    for section in odr.roads[road_index].lane_sections:
        if lane_id in section.by_id:
            return section.by_id[lane_id]
    raise KeyError(lane_id)


def test_signals_hang_over_driving_lanes_and_stand_on_poles_beside_them(tavf_dlr_build, esmini):
    odr = load_opendrive(tavf_dlr_build / "tavf-dlr.xodr")
    parts = scene_solid_parts(odr, None)
    assert_all_manifold(parts)
    signals = [s for s in parts.solids if s.kind == "signal"]
    assert len(signals) >= 300
    # netconvert puts every traffic light at its lane's centre with zOffset 5: no pole may block the lane
    assert min(s.mesh.vertices[:, 2].min() for s in signals) >= 4.99
    odr, surface = esmini("straight_500m_signs.xodr")  # signs at t = +-3.57 beside the lanes
    sign = next(s for s in scene_solid_parts(odr, surface).solids if s.source == "road 1 signal 1")
    assert sign.mesh.vertices[:, 2].min() == pytest.approx(0.0, abs=1e-9)
    assert sign.mesh.vertices[:, 2].max() == pytest.approx(1.7 + 0.61, abs=1e-9)


def test_town07_has_only_junction_curbs_and_does_not_fail(shared):
    odr = load_opendrive(shared("xodr", "libopendrive", "test.xodr"))
    surface = road_surface(odr, 0.1)
    parts = scene_solid_parts(odr, surface)
    assert parts.solids and all(s.source.startswith("junction ") for s in parts.solids)
    assert_all_manifold(parts)
    assert len(scene_solids(odr, surface).faces) == sum(s.triangles for s in parts.solids)


def _osm_buildings(osm_path):
    root = parse_safe(read_xml_source(osm_path))
    return {way.get("id"): {tag.get("k"): tag.get("v") for tag in way.findall("tag")}
            for way in root.findall("way") if any(tag.get("k") == "building" for tag in way.findall("tag"))}


def test_jungfernstieg_buildings(jungfernstieg_build):
    odr = load_opendrive(jungfernstieg_build / "jungfernstieg.xodr")
    osm = jungfernstieg_build / "source" / "jungfernstieg.osm"
    surface = road_surface(odr, 0.1)
    parts = scene_solid_parts(odr, surface, osm)
    assert_all_manifold(parts)
    buildings = [s for s in parts.solids if s.kind == "building"]
    expected = {way for way, tags in _osm_buildings(osm).items() if vertical_extent(tags) is not None}
    found = {s.source.split()[2] for s in buildings}
    assert found == expected
    # a tagged height is the height above the ground (the road level here), foundation below
    tall = next(way for way, tags in _osm_buildings(osm).items() if tags.get("height") == "22.5")
    solid = next(s for s in buildings if s.source == f"osm way {tall}")
    assert solid.mesh.vertices[:, 2].max() == pytest.approx(22.5, abs=1e-6)
    assert solid.mesh.vertices[:, 2].min() == pytest.approx(-0.5, abs=1e-6)
    # placed with the OpenDRIVE's georeference: the footprint corners are where pyproj puts the OSM nodes
    root = parse_safe(read_xml_source(osm))
    nodes = {n.get("id"): (float(n.get("lon")), float(n.get("lat"))) for n in root.findall("node")}
    way = next(w for w in root.findall("way") if w.get("id") == tall)
    lonlat = np.array([nodes[nd.get("ref")] for nd in way.findall("nd")])
    x, y = odr.georeference.wgs84_to_local(lonlat[:, 0], lonlat[:, 1])
    corners = solid.mesh.vertices[:, :2]
    distance = np.min(np.hypot(corners[:, None, 0] - x[None, :], corners[:, None, 1] - y[None, :]), axis=0)
    assert distance.max() < 1e-6


def test_building_heights_from_tags():
    assert vertical_extent({"building": "yes", "height": "12.5 m"}) == (-0.5, 12.5)
    assert vertical_extent({"building": "yes", "building:levels": "5", "roof:levels": "1"}) == (-0.5, 18.0)
    assert vertical_extent({"building": "yes"}) == (-0.5, 10.0)
    assert vertical_extent({"building": "roof"}) == (4.0, 5.0)
    assert vertical_extent({"building": "yes", "min_height": "3", "height": "9"}) == (3.0, 9.0)
    assert vertical_extent({"building": "yes", "layer": "-1"}) is None
    assert vertical_extent({"building": "no"}) is None
    assert vertical_extent({"building": "yes", "height": "5000"}) == (-0.5, 1000.0)
    assert parse_length("40 ft") == pytest.approx(12.192)
    assert parse_length("tall") is None


def test_broken_osm_is_one_line_error(tmp_path):
    osm = tmp_path / "broken.osm"
    osm.write_text('<?xml version="1.0"?>\n<osm version="0.6">\n<node id="1" lat="53.5" lon="9.9"/>\n<way id="2">')
    with pytest.raises(InputError) as error:
        read_footprints(osm)
    assert str(osm) in str(error.value) and "\n" not in str(error.value)


def _objects_doc(tmp_path, objects: str):
    path = tmp_path / "objects.xodr"
    path.write_text(document(road_xml('<geometry s="0" x="0" y="0" hdg="0" length="100"><line/></geometry>', 100.0,
                                      extra=f"<objects>{objects}</objects>")))
    return load_opendrive(path)


def test_bad_outlines_are_skipped_or_cleaned(tmp_path):
    odr = _objects_doc(tmp_path, """
      <object id="flat" s="10" t="5" zOffset="0" hdg="0" pitch="0" roll="0">
        <outlines><outline id="0" closed="true">
          <cornerLocal u="0" v="0" z="0" height="0"/><cornerLocal u="1" v="0" z="0" height="0"/>
          <cornerLocal u="1" v="1" z="0" height="0"/></outline></outlines></object>
      <object id="line" s="20" t="5" zOffset="0" hdg="0" pitch="0" roll="0">
        <outlines><outline id="0" closed="true">
          <cornerLocal u="0" v="0" z="0" height="2"/><cornerLocal u="1" v="0" z="0" height="2"/>
          <cornerLocal u="2" v="0" z="0" height="2"/></outline></outlines></object>
      <object id="bowtie" s="30" t="5" zOffset="0" hdg="0" pitch="0" roll="0">
        <outlines><outline id="0" closed="true">
          <cornerLocal u="0" v="0" z="0" height="2"/><cornerLocal u="2" v="2" z="0" height="2"/>
          <cornerLocal u="2" v="0" z="0" height="2"/><cornerLocal u="0" v="2" z="0" height="2"/></outline></outlines>
      </object>
      <object id="fence" s="40" t="5" zOffset="0" hdg="0" pitch="0" roll="0">
        <outlines><outline id="0" closed="false">
          <cornerRoad s="40" t="5" dz="0" height="1.5"/><cornerRoad s="60" t="5" dz="0" height="1.5"/>
          <cornerRoad s="60" t="9" dz="0" height="1.5"/></outline></outlines></object>""")
    parts = scene_solid_parts(odr, None)
    assert_all_manifold(parts)
    assert sorted(s.source for s in parts.solids) == ["road 1 object bowtie outline 0", "road 1 object fence outline 0"]
    assert any(line.startswith("road 1 object flat") for line in parts.skipped)
    assert any(line.startswith("road 1 object line") and "no area" in line for line in parts.skipped)
    bowtie = next(s for s in parts.solids if "bowtie" in s.source).mesh.to_trimesh()
    assert bowtie.volume == pytest.approx(2 * 2.0 * 2.0 / 2, rel=1e-9)  # two triangles of 1 m2 each, 2 m high
    fence = next(s for s in parts.solids if "fence" in s.source).mesh.to_trimesh()
    assert fence.volume == pytest.approx(0.1 * 1.5 * 24.0, rel=0.02)


def test_hostile_repeats_are_refused_not_ground_through(tmp_path):
    odr = _objects_doc(tmp_path, """
      <object id="dust" s="0" t="5" height="1"><repeat s="0" length="100" distance="0.00001" tStart="5" tEnd="5"/>
      </object>
      <object id="wall" s="0" t="5" height="1"><repeat s="10" length="20" distance="0" tStart="5" tEnd="5"/></object>""")
    parts = scene_solid_parts(odr, None)
    assert [s.source for s in parts.solids] == ["road 1 object wall repeat 0"]
    refused = "road 1 object dust: repeat would place 10000001 instances (distance 1e-05 m over 100.0 m; limit 10000)"
    assert parts.skipped == (refused,)
    wall = parts.solids[0].mesh.to_trimesh()  # 20 m long, DEFAULT_POST thick, 1 m high
    assert wall.volume == pytest.approx(20.0 * 0.1 * 1.0, rel=1e-9)


# a left turn of a one-lane connecting road, as netconvert draws Glasshouse Yard into Goswell Road (London):
# the lane (1.85 m, right of the reference line) has its centre on a circle of TURN_RADIUS around TURN_CENTRE
LANE_WIDTH = 1.85
TURN_CENTRE = np.array([30.0, 7.5])
TURN_RADIUS = 7.5 + LANE_WIDTH / 2


def _turn_with_buildings(tmp_path):
    """An OpenDRIVE (straight 30 m east, a 90-degree left arc, straight 30 m north; one driving lane) and an
    OSM file with two buildings: way 1 pokes a corner into the turn 0.7 m inside the lane centre, way 2 stands
    1.8 m beside the straight lane's centre."""
    from tavf_mapkit.opendrive.georef import GeoReference

    proj = "+proj=tmerc +lat_0=51.5214 +lon_0=-0.0975 +k=1 +x_0=0 +y_0=0 +ellps=WGS84 +units=m +no_defs"
    lanes = f"""
        <laneSection s="0">
          <center><lane id="0" type="none" level="false"/></center>
          <right><lane id="-1" type="driving" level="false">
            <width sOffset="0" a="{LANE_WIDTH}" b="0" c="0" d="0"/></lane></right>
        </laneSection>"""
    arc = 7.5 * math.pi / 2
    roads = [road_xml('<geometry s="0" x="0" y="0" hdg="0" length="30"><line/></geometry>', 30.0, lanes,
                      road_id="1"),
             road_xml(f'<geometry s="0" x="30" y="0" hdg="0" length="{arc!r}"><arc curvature="{1 / 7.5!r}"/>'
                      "</geometry>", arc, lanes, road_id="2"),
             road_xml(f'<geometry s="0" x="37.5" y="7.5" hdg="{math.pi / 2!r}" length="30"><line/>'
                      "</geometry>", 30.0, lanes, road_id="3")]
    xodr = tmp_path / "turn.xodr"
    xodr.write_text(document(*roads, header_extra=f"<geoReference><![CDATA[{proj}]]></geoReference>"))
    # way 1: a 6 m square north-west of its south-east corner, which lies on the turn's bisector
    corner = TURN_CENTRE + (TURN_RADIUS - 0.7) * np.array([math.cos(-math.pi / 4), math.sin(-math.pi / 4)])
    square = corner + np.array([[0.0, 0.0], [0.0, 6.0], [-6.0, 6.0], [-6.0, 0.0]])
    # way 2: 10 m x 4 m south of the straight road, 1.8 m from its lane's centre (y = -LANE_WIDTH / 2)
    beside = np.array([[5.0, -1.8], [15.0, -1.8], [15.0, -5.8], [5.0, -5.8]]) - [0.0, LANE_WIDTH / 2]
    geo = GeoReference(proj)
    nodes, ways = [], []
    for way, ring in ((1, square), (2, beside)):
        lon, lat = geo.local_to_wgs84(ring[:, 0], ring[:, 1])
        ids = [10 * way + k for k in range(len(ring))]
        nodes += [f'<node id="{i}" lat="{la!r}" lon="{lo!r}"/>'
                  for i, lo, la in zip(ids, np.asarray(lon).tolist(), np.asarray(lat).tolist())]
        refs = "".join(f'<nd ref="{i}"/>' for i in ids + ids[:1])
        ways.append(f'<way id="{way}">{refs}<tag k="building" v="yes"/></way>')
    osm = tmp_path / "turn.osm"
    osm.write_text('<?xml version="1.0"?>\n<osm version="0.6">\n' + "\n".join(nodes + ways) + "\n</osm>\n")
    return xodr, osm


def _footprint(solid):
    """The plan-view footprint of an extruded building solid (the union of its bottom faces)."""
    import shapely

    triangles = solid.mesh.vertices[solid.mesh.faces]
    bottom = np.all(triangles[:, :, 2] == solid.mesh.vertices[:, 2].min(), axis=1)
    return shapely.union_all(shapely.polygons(triangles[bottom][:, :, :2]))


def test_buildings_leave_the_swept_path_of_a_tight_turn_free(tmp_path):
    """A building corner that OSM puts into a tight turn is cut back to the swept path of a car on the lane
    (not only 0.5 m from the lane's surface, which leaves a car 1.96 m wide no room in a 1.85 m lane); a
    building beside a straight lane keeps its footprint; the tiled mesher makes the same solids."""
    import shapely

    from tavf_mapkit.mesh.folder import write_mesh_folder
    from tavf_mapkit.mesh.solid_buildings import OVERHEAD_CLEARANCE, building_parts
    from tavf_mapkit.mesh.swept_path import followable, swept_width
    from tavf_mapkit.mesh.tiled import read_labelled_index, read_labelled_tile

    xodr, osm = _turn_with_buildings(tmp_path)
    odr = load_opendrive(xodr)
    surface = road_surface(odr, 0.05)
    buildings = [s for s in scene_solid_parts(odr, surface, osm).solids if s.kind == "building"]
    turn = [s for s in buildings if s.source.startswith("osm way 1 ")]
    ground = [s for s in turn if s.mesh.vertices[:, 2].min() < 0]
    assert ground and [s.source for s in turn if s not in ground] == ["osm way 1 passage 1 over the road"]
    over = [s.mesh.vertices[:, 2].min() for s in turn if s not in ground]
    assert over == pytest.approx([OVERHEAD_CLEARANCE])
    # the lane's centre line through the turn, to a micrometre
    angle = np.linspace(-math.pi / 2, 0.0, 20001)
    centre = shapely.LineString(TURN_CENTRE + TURN_RADIUS * np.column_stack([np.cos(angle), np.sin(angle)]))
    need = float(swept_width(np.array([1.0 / TURN_RADIUS]))[0])
    assert need > 1.7
    # (a piece sharper than the wheelbase, a U-turn's, would count at the straight width)
    assert followable(swept_width(np.array([1.0 / TURN_RADIUS, 0.5]))).tolist() == [need, 1.25]
    assert min(_footprint(s).distance(centre) for s in ground) >= need - 1e-3
    # beside the straight lane: the whole footprint (as OSM's 1e-7 degree coordinates place it), uncut
    straight = [s for s in buildings if s.source.startswith("osm way 2")]
    assert [s.source for s in straight] == ["osm way 2"]
    as_mapped = dict((where, polygon) for where, polygon, _ in building_parts(odr, osm)[0])["osm way 2"]
    assert _footprint(straight[0]).symmetric_difference(as_mapped).area < 1e-6

    # the tiled mesher makes the same buildings
    write_mesh_folder(odr, tmp_path / "mesh", osm_path=osm, eps=0.05)
    labelled = tmp_path / "mesh" / "labelled"
    tiled = [solid for name in read_labelled_index(labelled)["tiles"]
             for solid in read_labelled_tile(labelled / f"{name}.npz")[1].solids if solid.kind == "building"]
    assert sorted(s.source for s in tiled) == sorted(s.source for s in buildings)
    whole = {s.source: s.mesh for s in buildings}
    for solid in tiled:
        assert np.array_equal(solid.mesh.faces, whole[solid.source].faces)
        assert np.array_equal(solid.mesh.vertices, whole[solid.source].vertices)
