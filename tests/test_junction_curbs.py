"""Curbs around junctions: manifold strips on the open sides of every junction, never across an entry,
never on a lane and never in the swept path of a car following a driving lane."""

from __future__ import annotations

import numpy as np
import pytest
import shapely

from tavf_mapkit.mesh import road_surface
from tavf_mapkit.mesh.labelled import KIND_CODE
from tavf_mapkit.mesh.solid_curbs import CURB_FOUNDATION
from tavf_mapkit.mesh.solid_junction_curbs import JUNCTION_CURB_HEIGHT, junction_curb_solids
from tavf_mapkit.mesh.solids import SceneSolids
from tavf_mapkit.mesh.swept_path import (
    DESIGN_HALF_WIDTH,
    DESIGN_WHEELBASE,
    MARGIN,
    STEP,
    swept_width,
    wheelbase_curvature,
)
from tavf_mapkit.opendrive import load_opendrive
from tavf_mapkit.opendrive.sampling import sample_lanes, sample_lanes_at
from tests.conftest import shared_path
from tests.test_solids import assert_all_manifold


def _plan(mesh):
    """Plan-view footprint of a mesh (union of its projected faces)."""
    top = mesh.vertices[mesh.faces][:, :, :2]
    triangles = shapely.polygons(np.concatenate([top, top[:, :1]], axis=1))
    return shapely.union_all(triangles[shapely.area(triangles) > 1e-12])


def _driving_centres(odr, step):
    """(points (n, 2), curvature (n,)) of every driving lane's centre line."""
    sampling = sample_lanes(odr, step)
    driving = np.char.lower(sampling.lane_type.astype(str)) == "driving"
    points = sampling.center_points(with_height=False)[driving, :2]
    return points, wheelbase_curvature(sampling.pair_lane[driving], points)


def _road_ends(odr):
    """Start and end line of every lane of every connecting road."""
    arrays = odr.arrays
    sections, s = [], []
    for road_index, road in enumerate(odr.roads):
        if not road.in_junction:
            continue
        mine = np.flatnonzero(arrays.section_road == road_index)
        sections += [mine[0], mine[-1]]
        s += [arrays.section_s0[mine[0]], arrays.section_end[mine[-1]]]
    sampling = sample_lanes_at(odr, np.array(sections), np.array(s))
    return shapely.linestrings(np.stack([sampling.points_at(sampling.t_inner)[:, :2],
                                         sampling.points_at(sampling.t_outer)[:, :2]], axis=1))


def assert_junction_curbs(odr, surface, curbs):
    """Manifold, 0.15 m above / 0.2 m below the junction border they stand on, beside a junction and outside
    every lane, not across a connecting road's end, and clear of the swept path of every driving lane."""
    assert curbs
    assert_all_manifold(SceneSolids(tuple(curbs), ()))
    plan = surface.vertices[surface.faces][:, :, :2]
    triangles = shapely.polygons(np.concatenate([plan, plan[:, :1]], axis=1))
    road = shapely.union_all(triangles)
    junction_faces = surface.select(surface.kind == KIND_CODE["junction"])
    junction_plan = _plan(junction_faces)
    border_tree = shapely.STRtree(shapely.points(junction_faces.vertices[:, :2]))
    # at the mesher's own samples (the same curvature), and four times finer for the plain half car + margin
    centres, curvature = _driving_centres(odr, STEP)
    centre_tree = shapely.STRtree(shapely.points(centres))
    fine, _ = _driving_centres(odr, STEP / 4)
    fine_tree = shapely.STRtree(shapely.points(fine))
    ends = _road_ends(odr)
    for solid in curbs:
        mesh = solid.mesh
        footprint = _plan(mesh)
        # on the road nowhere by more than the 1 mm the curve repair may move a border (where a nearly flat piece
        # became a line, a lane border steps by up to its lever x half the piece's turn: a sliver under 1 mm wide)
        on_road = shapely.intersection(footprint, road)
        assert shapely.area(on_road) < 5e-4 or shapely.buffer(on_road, -0.5e-3).is_empty, solid.source
        assert shapely.distance(footprint, junction_plan) < 2.5e-3, solid.source
        # every corner has a twin 0.35 m below (top 0.15 m above the border, foundation 0.2 m below it)
        xy, inverse = np.unique(np.round(mesh.vertices[:, :2], 9), axis=0, return_inverse=True)
        inverse = inverse.ravel()
        high = np.full(len(xy), -np.inf)
        low = np.full(len(xy), np.inf)
        np.maximum.at(high, inverse, mesh.vertices[:, 2])
        np.minimum.at(low, inverse, mesh.vertices[:, 2])
        assert np.allclose(high - low, JUNCTION_CURB_HEIGHT + CURB_FOUNDATION, atol=1e-6), solid.source
        # the top stands 0.15 m above the nearest junction vertex, within the slope over a curb width (Town07's
        # junction faces slope up to 60 % where its overlapping connecting roads differ in height)
        nearest = border_tree.query_nearest(shapely.points(xy))[1]
        off = np.abs(high - junction_faces.vertices[nearest, 2] - JUNCTION_CURB_HEIGHT)
        assert np.all(off < 0.1), (solid.source, off.max(), xy[np.argmax(off)])
        assert np.all(mesh.kind == KIND_CODE["curb"])
        # no curb across an entry: at most a corner touches a connecting road's end line
        touching = ends[shapely.intersects(ends, shapely.buffer(footprint, 0.01))]
        assert shapely.length(shapely.intersection(touching, shapely.buffer(footprint, 0.01))).max(
            initial=0.0) < 0.05, solid.source
        # clear of every driving lane's swept path
        near = centre_tree.query(footprint, predicate="dwithin", distance=5.0)
        distance = shapely.distance(shapely.points(centres[near]), footprint)
        needed = swept_width(curvature[near])
        assert np.all(distance >= needed - 1e-3), (solid.source, float((needed - distance).max()))
        assert not fine_tree.query(footprint, predicate="dwithin", distance=DESIGN_HALF_WIDTH + MARGIN - 1e-3).size



def test_swept_width_is_half_a_car_plus_its_curve_widening():
    assert swept_width(np.array([0.0]))[0] == pytest.approx(DESIGN_HALF_WIDTH + MARGIN)
    # a car whose front axle follows a 10 m circle: its rear axle runs on sqrt(10^2 - L^2)
    radius = 10.0
    assert swept_width(np.array([1 / radius]))[0] == pytest.approx(
        DESIGN_HALF_WIDTH + MARGIN + radius - np.sqrt(radius**2 - DESIGN_WHEELBASE**2))
    assert np.all(np.diff(swept_width(np.linspace(0, 1 / DESIGN_WHEELBASE, 50))) > 0)  # tighter is wider


def test_wheelbase_curvature_of_a_circle_a_kink_and_separate_lines():
    angle = np.arange(0, 5.0, 0.05)  # a 10 m circle sampled every 0.5 m, one point repeated
    circle = np.column_stack([10 * np.cos(angle), 10 * np.sin(angle)])
    straight = np.column_stack([100 + 0.5 * np.arange(40), np.zeros(40)])
    points = np.concatenate([circle[:50], circle[49:50], circle[50:], straight])
    lane = np.r_[np.zeros(len(circle) + 1, dtype=int), np.ones(40, dtype=int)]
    curvature = wheelbase_curvature(lane, points)
    inside = np.r_[np.zeros(4, bool), np.ones(len(circle) - 7, bool), np.zeros(4, bool)]
    assert np.allclose(curvature[:len(circle) + 1][inside], 0.1, rtol=1e-3)
    assert curvature[50] == curvature[49]  # the repeated point
    assert np.all(curvature[len(circle) + 1:] == 0.0)  # the straight lane does not see the circle beside it
    # a 10 degree kink counts over one wheelbase
    kink = np.radians(10.0)
    leg = 0.5 * np.arange(1, 20)[:, None]
    bent = np.concatenate([[[0.0, 0.0]], leg * [1.0, 0.0], leg[-1] * [1.0, 0.0] + leg * [np.cos(kink), np.sin(kink)]])
    assert wheelbase_curvature(np.zeros(len(bent), dtype=int), bent).max() == pytest.approx(kink / DESIGN_WHEELBASE)


def test_town07_junction_curbs(shared):
    odr = load_opendrive(shared("xodr", "libopendrive", "test.xodr"))
    surface = road_surface(odr, 0.1)
    curbs, skipped = junction_curb_solids(odr, surface)
    assert not skipped
    assert_junction_curbs(odr, surface, curbs)


@pytest.mark.parametrize("name", ["multi_intersections.xodr", "fabriksgatan.xodr"])
def test_junctions_ringed_by_sidewalks_get_no_junction_curb(name):
    # esmini's junctions are ringed by sidewalk connecting lanes: no open side, so no junction curb
    odr = load_opendrive(shared_path("xodr", "esmini", name))
    assert junction_curb_solids(odr, road_surface(odr, 0.05)) == ([], [])


@pytest.mark.slow
@pytest.mark.parametrize("build", ["jungfernstieg_build", "tavf_dlr_build"])
def test_junction_curbs_of_the_real_builds(build, request):
    folder = request.getfixturevalue(build)
    odr = load_opendrive(next(folder.glob("*.xodr")))
    surface = road_surface(odr, 0.1)
    curbs, skipped = junction_curb_solids(odr, surface)
    assert not skipped
    assert_junction_curbs(odr, surface, curbs)
