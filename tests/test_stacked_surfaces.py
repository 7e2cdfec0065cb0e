"""Roads that overlap at different heights: a road-side surface standing on another road's driving lane gives
way to it (mesh/stacked.py), and where a junction's connecting lanes disagree in height its surface fades from
one to the other instead of stepping (mesh/junctions.py, ``Drape``). Both on small synthetic maps, so they run
in a second; CARLA's Town07 has both (tests/test_mesh_reference.py checks its lane borders)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tavf_mapkit.mesh.folder import write_mesh_folder
from tavf_mapkit.mesh.labelled import KIND_CODE
from tavf_mapkit.mesh.planindex import PlanIndex
from tavf_mapkit.mesh.stacked import STACK_CLEARANCE, STACK_MIN
from tavf_mapkit.mesh.surface import build_road_surface
from tavf_mapkit.opendrive import loads_opendrive
from tests.test_mesh_tiled import files
from tests.xodr_factory import document


def _lane(lane_id, kind, width):
    return (f'<lane id="{lane_id}" type="{kind}" level="false">'
            f'<width sOffset="0" a="{width}" b="0" c="0" d="0"/></lane>')


SIDEWALK = f'<right>{_lane(-1, "sidewalk", 2)}</right>'
TWO_WAY = f'<left>{_lane(1, "driving", 3.5)}</left><right>{_lane(-1, "driving", 3.5)}</right>'


def _road(road_id, x, y, hdg, length, lanes, z=0.0, junction="-1"):
    return (f'<road id="{road_id}" length="{length}" junction="{junction}"><link/><planView>'
            f'<geometry s="0" x="{x}" y="{y}" hdg="{hdg}" length="{length}"><line/></geometry></planView>'
            f'<elevationProfile><elevation s="0" a="{z}" b="0" c="0" d="0"/></elevationProfile>'
            f'<lanes><laneSection s="0"><center><lane id="0" type="none"/></center>{lanes}</laneSection>'
            '</lanes>'
            '</road>')


# a two-way road along x (lanes from y=-3.5 to 3.5); the sidewalks of a side street as a road of their own,
# 15 cm up, reaching 2 m into its left lane (Town07 draws them so); a footbridge 5 m up; a shoulder at road
# level
STACKED = document(
    _road("1", 0, 0, 0, 300, TWO_WAY),
    _road("2", 50, 20, -math.pi / 2, 18.5, SIDEWALK, z=0.15),
    _road("3", 72, 20, -math.pi / 2, 40, SIDEWALK, z=5.0),
    _road("4", 90, 5, -math.pi / 2, 3.5, SIDEWALK.replace("sidewalk", "shoulder")))


def _heights(mesh, points):
    """Per plan point: the heights of every face of ``mesh`` over it."""
    triangles = mesh.vertices[mesh.faces]
    point, face = PlanIndex(triangles[:, :, :2], 1e-9).covering(points, 1e-9)
    a, b, c = (triangles[face, k] for k in range(3))
    normal = np.cross(b - a, c - a)
    dx, dy = points[point, 0] - a[:, 0], points[point, 1] - a[:, 1]
    z = a[:, 2] - (dx * normal[:, 0] + dy * normal[:, 1]) / normal[:, 2]
    return [z[point == k] for k in range(len(points))]


def _plan_area(mesh, road_index):
    corners = mesh.vertices[mesh.faces[mesh.road_index == road_index]][:, :, :2]
    u, v = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    return float(np.sum(0.5 * np.abs(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0])))


def test_a_road_side_surface_standing_on_a_driving_lane_gives_way_to_it():
    odr = loads_opendrive(STACKED)
    surface = build_road_surface(odr, 0.05)
    mesh = surface.mesh
    # what a wheel ray finds on the driving lanes: the lane itself, or a deck a car passes under
    gx, gy = np.meshgrid(np.arange(0.25, 300.0, 0.5), np.arange(-3.4, 3.45, 0.2))
    points = np.column_stack([gx.ravel(), gy.ravel()])
    rise = np.array([np.max(z) - np.min(z) for z in _heights(mesh, points)])
    assert not np.any((rise > STACK_MIN) & (rise < STACK_CLEARANCE))
    assert np.any(rise > 4.9)  # the footbridge is still there
    # the side street's sidewalk is cut exactly at the lane's edge (y = 3.5), nothing else of it is lost
    assert _plan_area(mesh, 1) == pytest.approx(2.0 * (18.5 - 2.0), abs=1e-6)
    assert _plan_area(mesh, 2) == pytest.approx(2.0 * 40.0, abs=1e-6)
    assert _plan_area(mesh, 3) == pytest.approx(2.0 * 3.5, abs=1e-6)  # level with the road: left alone
    assert sorted(surface.given_way) == [1] and surface.given_way[1].area == pytest.approx(4.0, abs=1e-6)
    sidewalk = mesh.vertices[np.unique(mesh.faces[mesh.road_index == 1])]
    assert sidewalk[:, 1].min() == pytest.approx(3.5, abs=1e-9) and np.allclose(sidewalk[:, 2], 0.15)
    # (s, t) of the new corners lie on the sidewalk's own parametrisation: s = 20 - y
    uv = mesh.uv[np.unique(mesh.faces[mesh.road_index == 1])]
    assert np.allclose(uv[:, 0], 20.0 - sidewalk[:, 1], atol=1e-9)


def test_giving_way_does_not_depend_on_the_batch(tmp_path):
    """The sidewalk road and the road it stands on are meshed in different batches (their units lie in
    different tiles): the batch of the sidewalk meshes the other road's driving lanes itself, with the same
    result."""
    odr = loads_opendrive(STACKED)
    one = write_mesh_folder(odr, tmp_path / "one", batch_work=1e12, preview=False)
    many = write_mesh_folder(odr, tmp_path / "many", batch_work=1.0, preview=False)
    assert one == many and files(tmp_path / "one") == files(tmp_path / "many")
    assert one["triangles"]["lanes"] > 0


def test_a_junction_fades_between_connecting_lanes_that_disagree_in_height():
    """Two connecting lanes of a junction overlap by 1.5 m, 0.4 m apart in height (CARLA's Town07 has a
    junction whose through lane runs 0.6 m below the turning lanes crossing it). No surface fits both; the
    junction's used to step by half the difference at the edge of each lane's footprint (0.2 m within a 0.25 m
    triangle), which a car's wheel took for a curb. Now it fades across the overlap: no steeper than the
    difference over the overlap's width, and it still meets each lane where the other one is not."""
    lane = f'<right>{_lane(-1, "driving", 3.5)}</right>'
    odr = loads_opendrive(document(_road("10", 0, 0, 0, 20, lane, junction="5"),
                                   _road("11", 0, -2, 0, 20, lane, z=0.4, junction="5"),
                                   tail='<junction id="5" name="j"/>'))
    mesh = build_road_surface(odr, 0.05).mesh
    assert np.all(mesh.kind == KIND_CODE["junction"])
    y = np.arange(-5.45, -0.05, 0.05)
    line = np.column_stack([np.full(len(y), 10.0), y])
    z = np.array([np.max(h) for h in _heights(mesh, line)])
    # where one lane is alone, the surface is its height (within eps)
    assert z[y < -3.55] == pytest.approx(0.4, abs=0.05) and z[y > -1.95] == pytest.approx(0.0, abs=0.05)
    assert np.max(np.abs(np.diff(z)) / 0.05) < 0.4 / 1.5 * 1.5
