"""Lane surface meshes: tolerance for every geometry and lateral record, topology, curbs, degenerate input."""

from __future__ import annotations

import numpy as np
import pytest
import shapely

from tavf_mapkit.mesh import KIND_CODE, build_road_surface, road_surface
from tavf_mapkit.mesh.adaptive import adaptive_samples
from tavf_mapkit.mesh.cleanup import face_cross, triangle_areas
from tavf_mapkit.mesh.measure import distance_to_mesh
from tavf_mapkit.opendrive import load_opendrive, loads_opendrive
from tavf_mapkit.opendrive.sampling import sample_lanes
from tests.conftest import shared_path
from tests.xodr_factory import document, road_xml

ELEVATION = ('<elevationProfile><elevation s="0" a="2" b="0.03" c="0.0004" d="-1e-6"/></elevationProfile>')
SUPER = '<lateralProfile><superelevation s="0" a="0.02" b="0.0015" c="0" d="-2e-8"/></lateralProfile>'
WIDE_LANES = """
    <laneSection s="0">
      <left>
        <lane id="2" type="sidewalk" level="false"><width sOffset="0" a="2" b="0.01" c="0" d="0"/></lane>
        <lane id="1" type="driving" level="false"><width sOffset="0" a="3.5" b="0" c="0.002" d="-2e-5"/></lane>
      </left>
      <center><lane id="0" type="none" level="false"/></center>
      <right>
        <lane id="-1" type="driving" level="false"><width sOffset="0" a="3" b="0" c="0" d="0"/>
          <width sOffset="40" a="3" b="0.05" c="-0.001" d="0"/></lane>
        <lane id="-2" type="shoulder" level="false"><border sOffset="0" a="-6" b="-0.02" c="0" d="0"/></lane>
      </right>
    </laneSection>"""

CASES = {
    "line+elevation": ('<geometry s="0" x="0" y="0" hdg="0.3" length="120"><line/></geometry>', 120, ELEVATION, ""),
    "arc": ('<geometry s="0" x="0" y="0" hdg="0" length="150"><arc curvature="0.025"/></geometry>', 150, "", ""),
    "tight arc": ('<geometry s="0" x="0" y="0" hdg="0" length="40"><arc curvature="-0.08"/></geometry>', 40, "", ""),
    "spiral": ('<geometry s="0" x="0" y="0" hdg="0" length="100"><spiral curvStart="0" curvEnd="0.04"/></geometry>',
               100, "", ""),
    "poly3": ('<geometry s="0" x="0" y="0" hdg="0" length="80"><poly3 a="0" b="0" c="0.004" d="-4e-5"/></geometry>',
              80, "", ""),
    # @length is the curve's arc length: s is arc length, so a longer @length would stand still at the end
    "paramPoly3": (('<geometry s="0" x="0" y="0" hdg="0" length="91.90718624256009"><paramPoly3 aU="0" bU="90" '
                   'cU="0" dU="0" aV="0" bV="0" cV="25" dV="-8" pRange="normalized"/></geometry>'), 91.90718624256009,
                   "", ""),
    "superelevation": ('<geometry s="0" x="0" y="0" hdg="0" length="120"><arc curvature="0.01"/></geometry>', 120,
                       ELEVATION + SUPER, ""),
    "laneOffset": ('<geometry s="0" x="0" y="0" hdg="0" length="100"><arc curvature="0.015"/></geometry>', 100, "",
                   '<laneOffset s="0" a="0" b="0.02" c="0.0005" d="-5e-6"/>'),
}


def _odr(geometry, length, extra="", lane_offset="", lanes=WIDE_LANES):
    return loads_opendrive(document(road_xml(geometry, length, lanes=lanes, extra=extra, lane_offset=lane_offset)))


def _exact_lane_points(odr, fractions=(0.0, 0.25, 0.5, 0.75, 1.0), step=0.05):
    """Dense points of the exact surface across every lane (lane heights applied like the mesh)."""
    sampling = sample_lanes(odr, step)
    h_in, h_out = sampling.heights()
    points = []
    for f in fractions:
        t = (1 - f) * sampling.t_inner + f * sampling.t_outer
        points.append(sampling.points_at(t, (1 - f) * h_in + f * h_out))
    return np.concatenate(points)


@pytest.mark.parametrize("case", sorted(CASES))
@pytest.mark.parametrize("eps", [0.1, 0.02])
def test_mesh_within_eps_of_exact_surface(case, eps):
    geometry, length, extra, lane_offset = CASES[case]
    odr = _odr(geometry, length, extra, lane_offset)
    mesh = road_surface(odr, eps)
    distance = distance_to_mesh(mesh.vertices, mesh.faces, _exact_lane_points(odr), search_radius=1.0)
    assert distance.max() <= eps + 1e-6, (case, distance.max())
    # and the tolerance is used, not wasted: a curved road gets far fewer cross-sections than a 0.5 m step
    assert adaptive_samples(odr, eps).s.size < length / 0.5 or case == "tight arc"


def test_sampling_adapts_to_curvature_and_eps():
    straight = _odr('<geometry s="0" x="0" y="0" hdg="0" length="200"><line/></geometry>', 200)
    arc = _odr('<geometry s="0" x="0" y="0" hdg="0" length="200"><arc curvature="0.02"/></geometry>', 200)
    n_straight = adaptive_samples(straight, 0.05).s.size
    n_arc_coarse = adaptive_samples(arc, 0.08).s.size
    n_arc_fine = adaptive_samples(arc, 0.02).s.size
    # the widening lane of the straight road needs a few; the arc needs many more, ~ 1/sqrt(eps)
    assert n_straight < n_arc_coarse < n_arc_fine
    assert 1.5 < n_arc_fine / n_arc_coarse < 2.6


def test_faces_up_labels_and_uv():
    geometry, length, extra, lane_offset = CASES["superelevation"]
    odr = _odr(geometry, length, extra, lane_offset)
    mesh = road_surface(odr, 0.05)
    normal = face_cross(mesh.vertices, mesh.faces)
    assert np.all(normal[:, 2] > 0)
    assert triangle_areas(mesh.vertices, mesh.faces).min() >= 1e-8
    assert set(np.unique(mesh.lane_id)) == {2, 1, -1, -2}
    kinds = {int(k) for k in np.unique(mesh.kind)}
    assert kinds == {KIND_CODE["driving"], KIND_CODE["sidewalk"], KIND_CODE["shoulder"]}
    assert np.all(mesh.road_index == 0)
    # uv = (s, t): the vertex is the exact surface point at (s, t) (no lane heights here)
    exact = odr.roads[0].surface_point(mesh.uv[:, 0], mesh.uv[:, 1])
    np.testing.assert_allclose(mesh.vertices, exact, atol=1e-9)
    # every face of lane -1 lies between the borders of lane -1
    right = mesh.select(mesh.lane_id == -1)
    assert np.all(right.uv[:, 1] <= 1e-9)


def _boundary_edges(faces):
    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    unique, count = np.unique(edges, axis=0, return_counts=True)
    assert count.max() <= 2, "an edge is shared by more than two triangles"
    return unique[count == 1]


def test_adjacent_lanes_share_border_vertices():
    geometry, length, extra, lane_offset = CASES["laneOffset"]
    odr = _odr(geometry, length, extra, lane_offset)
    mesh = road_surface(odr, 0.02)
    boundary = _boundary_edges(mesh.faces)
    # edges used by one triangle only lie on the road's outer borders or its two ends: no cracks between lanes
    t = mesh.uv[boundary, 1]
    s = mesh.uv[boundary, 0]
    sampling = sample_lanes(odr, 0.5)
    on_end = np.all(np.isclose(s, 0.0) | np.isclose(s, length), axis=1)
    left_t = odr.roads[0].lane_borders(0, s[:, 0])[2]
    right_t = odr.roads[0].lane_borders(0, s[:, 0])[-2]
    on_side = np.isclose(t[:, 0], left_t) | np.isclose(t[:, 0], right_t)
    assert np.all(on_end | on_side)
    assert len(sampling.s)  # the map has lanes at all
    # one connected sheet: Euler characteristic of a disc
    assert len(mesh.vertices) - len(np.unique(np.sort(mesh.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1),
                                              axis=0)) + len(mesh.faces) == 1


RAISED = """
    <laneSection s="0">
      <left>
        <lane id="2" type="sidewalk" level="false"><width sOffset="0" a="2" b="0" c="0" d="0"/>
          <height sOffset="0" inner="0.15" outer="0.15"/></lane>
        <lane id="1" type="driving" level="false"><width sOffset="0" a="3.5" b="0" c="0" d="0"/></lane>
      </left>
      <center><lane id="0" type="none" level="false"/></center>
      <right>
        <lane id="-1" type="driving" level="false"><width sOffset="0" a="3.5" b="0" c="0" d="0"/></lane>
        <lane id="-2" type="sidewalk" level="false"><width sOffset="0" a="2" b="0" c="0" d="0"/>
          <height sOffset="0" inner="0.12" outer="0.12"/><height sOffset="30" inner="0.2" outer="0.2"/></lane>
      </right>
    </laneSection>"""


def test_raised_sidewalks_get_curb_faces():
    odr = _odr('<geometry s="0" x="0" y="0" hdg="0" length="60"><arc curvature="0.01"/></geometry>', 60,
               lanes=RAISED)
    mesh = road_surface(odr, 0.05)
    curb = mesh.select(mesh.kind == KIND_CODE["curb"])
    normal = face_cross(curb.vertices, curb.faces)
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    assert np.abs(normal[:, 2]).max() < 1e-6  # vertical faces
    # curb faces look from the raised sidewalk towards the road: towards t = 0 at the inner curbs, away from
    # the road at the outer edges
    centre = curb.vertices[curb.faces].mean(axis=1)
    s = curb.uv[curb.faces][:, :, 0].mean(axis=1)
    t = curb.uv[curb.faces][:, :, 1].mean(axis=1)
    _x, _y, heading, _ = odr.roads[0].reference_line.evaluate(s)
    e_t = np.column_stack([-np.sin(heading), np.cos(heading)])
    facing = np.einsum("ij,ij->i", normal[:, :2], e_t) * np.sign(t)  # > 0: away from the road centre
    inner = np.isclose(np.abs(t), 3.5)
    assert np.all(facing[inner] < -0.99) and np.all(facing[~inner] > 0.99)
    # heights: curbs reach from 0 to 0.15 (left), 0.12 then 0.2 (right)
    z_top = curb.vertices[:, 2]
    assert np.isclose(z_top.max(), 0.2) and np.isclose(z_top.min(), 0.0)
    assert np.all(np.isfinite(centre))
    # the sidewalk surfaces are up there and face up
    walk = mesh.select(mesh.kind == KIND_CODE["sidewalk"])
    assert np.all(face_cross(walk.vertices, walk.faces)[:, 2] > 0)
    left = walk.select(walk.lane_id == 2)
    np.testing.assert_allclose(left.vertices[:, 2], 0.15, atol=1e-9)
    right = walk.select(walk.lane_id == -2)
    s_right = right.uv[:, 0]
    assert np.allclose(right.vertices[s_right > 30 + 1e-6, 2], 0.2)
    assert np.allclose(right.vertices[s_right < 30 - 2e-3, 2], 0.12)


def test_zero_length_geometries_and_sections_do_not_abort():
    # what netconvert writes: a zero-length geometry, a zero-length lane section, a zero-width lane
    geometry = ('<geometry s="0" x="0" y="0" hdg="0" length="20"><line/></geometry>'
                '<geometry s="20" x="20" y="0" hdg="0" length="0"><line/></geometry>'
                '<geometry s="20" x="20" y="0" hdg="0.2" length="0.0000001"><arc curvature="0.1"/></geometry>'
                '<geometry s="20.0000001" x="20" y="0" hdg="0.2" length="30"><arc curvature="0.01"/></geometry>')
    lanes = """
        <laneSection s="0"><center><lane id="0" type="none" level="false"/></center>
          <right><lane id="-1" type="driving" level="false"><width sOffset="0" a="3" b="0" c="0" d="0"/></lane>
                 <lane id="-2" type="driving" level="false"><width sOffset="0" a="0" b="0" c="0" d="0"/></lane></right>
        </laneSection>
        <laneSection s="10"><center><lane id="0" type="none" level="false"/></center>
          <right><lane id="-1" type="driving" level="false"><width sOffset="0" a="3" b="0" c="0" d="0"/></lane></right>
        </laneSection>
        <laneSection s="10"><center><lane id="0" type="none" level="false"/></center>
          <right><lane id="-1" type="driving" level="false"><width sOffset="0" a="3" b="0" c="0" d="0"/></lane></right>
        </laneSection>"""
    odr = loads_opendrive(document(road_xml(geometry, 50.0000001, lanes=lanes)))
    surface = build_road_surface(odr, 0.05)
    mesh = surface.mesh
    assert len(mesh.faces) > 0
    assert triangle_areas(mesh.vertices, mesh.faces).min() >= 1e-8
    assert np.all(face_cross(mesh.vertices, mesh.faces)[:, 2] > 0)
    # the heading jump of 0.2 rad at s = 20 is a kink of the surface: found and bridged, not refined into slivers
    assert surface.samples.discontinuities >= 1
    assert surface.samples.unresolved == 0


def test_invalid_eps_is_refused():
    odr = _odr(*CASES["arc"][:2])
    for eps in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="eps must be a positive number"):
            road_surface(odr, eps)


@pytest.mark.parametrize("name", ["fabriksgatan", "multi_intersections"])
def test_junction_surfaces_do_not_overlap(name):
    odr = load_opendrive(shared_path("xodr", "esmini", f"{name}.xodr"))
    surface = build_road_surface(odr, 0.05)
    mesh = surface.mesh
    junction = mesh.select(mesh.kind == KIND_CODE["junction"])
    assert len(junction.faces) and surface.junction_footprints
    assert np.all(face_cross(junction.vertices, junction.faces)[:, 2] > 0)
    assert triangle_areas(junction.vertices, junction.faces).min() >= 1e-8
    # no two triangles overlap in plan view: their areas add up to the area of their union
    plan = junction.vertices[junction.faces][:, :, :2]
    triangles = shapely.polygons(np.concatenate([plan, plan[:, :1]], axis=1))
    union = shapely.union_all(triangles)
    assert np.isclose(shapely.area(triangles).sum(), union.area, rtol=1e-6)
    # and they cover the junction footprints
    footprint = shapely.union_all(list(surface.junction_footprints.values()))
    assert np.isclose(union.area, footprint.area, rtol=1e-6)
    # connecting roads' own lane faces are replaced, except raised lanes (they keep their faces and curbs)
    raised = {(i, lane.id) for i, road in enumerate(odr.roads) for section in road.lane_sections
              for lane in section.lanes if any(h.inner or h.outer for h in lane.heights)}
    in_junction = np.array([road.in_junction for road in odr.roads])
    kept = (mesh.kind != KIND_CODE["junction"]) & (mesh.kind != KIND_CODE["curb"]) & in_junction[mesh.road_index]
    assert {(int(r), int(lane)) for r, lane in zip(mesh.road_index[kept], mesh.lane_id[kept])} <= raised
    # one junction surface per junction
    assert set(surface.junction_footprints) <= {j.id for j in odr.junctions}


def test_adaptive_samples_in_small_batches_are_the_same(monkeypatch):
    """A region's segments are sampled SEGMENTS_PER_CALL at a time (all at once they exceed the map's allocation
    budget: Columbus); every segment's deviation and every breakpoint's jump is its own, so batches of 7 give
    exactly the samples of one call."""
    import tavf_mapkit.mesh.adaptive as adaptive

    odr = load_opendrive(shared_path("xodr", "esmini", "multi_intersections.xodr"))
    whole = adaptive_samples(odr, 0.02)
    assert whole.segments > 7 * 3 and whole.discontinuities >= 0
    monkeypatch.setattr(adaptive, "SEGMENTS_PER_CALL", 7)
    batched = adaptive_samples(odr, 0.02)
    np.testing.assert_array_equal(batched.section, whole.section)
    np.testing.assert_array_equal(batched.s, whole.s)
    assert (batched.max_deviation, batched.discontinuities, batched.unresolved, batched.segments) == (
        whole.max_deviation, whole.discontinuities, whole.unresolved, whole.segments)


def test_rows_by_name_equals_a_mask_per_name():
    """junction_footprints groups lane rows by junction with one sort; the groups are a mask's per junction, in
    the same order (the polygons are united in that order)."""
    from tavf_mapkit.mesh.junctions import rows_by_name

    rng = np.random.default_rng(7)
    names = np.array(rng.choice(["", "10", "9", "1000", "a", "-1"], size=500), dtype=object)
    groups = list(rows_by_name(names))
    assert [name for name, _ in groups] == sorted(set(names))
    for name, rows in groups:
        np.testing.assert_array_equal(rows, np.flatnonzero(names == name))
    assert list(rows_by_name(np.array([], dtype=object))) == []
