"""The lane surface mesh against independent lane-border evaluations (libOpenDRIVE) of six real files."""

from __future__ import annotations

import gzip

import numpy as np
import pytest
import shapely

from tavf_mapkit.mesh import KIND_CODE, build_road_surface
from tavf_mapkit.mesh.cleanup import face_cross, triangle_areas
from tavf_mapkit.mesh.junctions import drape
from tavf_mapkit.mesh.kinds import DRIVABLE_KINDS
from tavf_mapkit.mesh.measure import distance_to_mesh
from tavf_mapkit.opendrive import load_opendrive
from tests.conftest import shared_path

CONTRADICTION_RADIUS = 0.5  # m
REFERENCE_FILES = ["crest-curve", "curves_elevation", "e6mini", "fabriksgatan", "multi_intersections", "test"]


def _xodr(name: str):
    if name == "test":
        return shared_path("xodr", "libopendrive", "test.xodr")
    return shared_path("xodr", "esmini", f"{name}.xodr")


def _reference(name: str):
    with gzip.open(shared_path("reference", "lane_borders", f"{name}.csv.gz"), "rt") as stream:
        rows = np.genfromtxt(stream, delimiter=",", names=True, dtype=None, encoding=None)
    return rows, np.column_stack([rows["x"], rows["y"], rows["z"]])


@pytest.mark.parametrize("eps", [0.05, 0.1])
@pytest.mark.parametrize("name", REFERENCE_FILES)
def test_reference_lane_borders_lie_on_the_mesh(name, eps):
    odr = load_opendrive(_xodr(name))
    surface = build_road_surface(odr, eps)
    rows, points = _reference(name)
    distance = distance_to_mesh(surface.mesh.vertices, surface.mesh.faces, points, search_radius=0.5)
    in_junction = np.array([odr.road_by_id[str(road)].in_junction for road in rows["road"]])
    # road-side lanes that stood on another road's driving lane gave way to it (mesh.stacked: Town07's side
    # street sidewalks, 12-15 cm above the through road); their border points there are above the mesh
    road_index = np.array([odr.road_index[str(road)] for road in rows["road"]])
    gave_way, inside = np.zeros(len(points), dtype=bool), np.zeros(len(points), dtype=bool)
    for road, region in surface.given_way.items():
        mine = np.flatnonzero(road_index == road)
        gave_way[mine] = shapely.contains_xy(region.buffer(1e-6), points[mine, 0], points[mine, 1])
        inside[mine] = shapely.contains_xy(region.buffer(-0.1), points[mine, 0], points[mine, 1])
    assert inside.any() == (name == "test")
    if inside.any():  # a driving lane 12-15 cm below them, and no road-side surface left at their height
        below = distance_to_mesh(surface.mesh.vertices, surface.mesh.faces, points[inside] - [0, 0, 0.1],
                                 search_radius=0.5)
        assert distance[inside].min() > 0.1 and below.max() < 0.05
    # every other border point of an ordinary road is within eps + 1 mm of the mesh
    ordinary = ~in_junction & ~gave_way
    assert distance[ordinary].max() <= eps + 1e-3, distance[ordinary].max()
    if in_junction.any():
        # junctions have one surface; where the file's connecting roads disagree in height (CARLA's Town07:
        # overlapping connecting lanes 0.65 m apart, neighbouring ones with 6 cm steps) no single surface
        # can be within eps of all of them. The allowance is that disagreement: max - min of the connecting
        # lanes' heights within CONTRADICTION_RADIUS of the point or of a corner of the junction triangle
        # under it. For all of esmini's junctions it is 0, and so it is for most of Town07's points.
        junction_points = points[in_junction]
        junction = surface.mesh.select(surface.mesh.kind == KIND_CODE["junction"])
        under = drape(junction_points[:, :2], junction)[1]
        spots = np.concatenate([junction_points[:, None, :2], junction.vertices[junction.faces[under]][:, :, :2]],
                               axis=1)
        spread = drape(spots.reshape(-1, 2), surface.junction_lanes, CONTRADICTION_RADIUS)[3]
        spread = spread.reshape(-1, 4).max(axis=1)
        excess = distance[in_junction] - spread
        assert excess.max() <= eps + 1e-3, excess.max()
        consistent = spread < 1e-3
        assert consistent.mean() > 0.5  # the allowance is the exception, not the rule
        assert distance[in_junction][consistent].max() <= eps + 1e-3


@pytest.mark.parametrize("name", REFERENCE_FILES)
def test_mesh_hygiene_on_real_files(name):
    odr = load_opendrive(_xodr(name))
    mesh = build_road_surface(odr, 0.05).mesh
    assert triangle_areas(mesh.vertices, mesh.faces).min() >= 1e-8
    drivable = np.isin(mesh.kind, [KIND_CODE[k] for k in DRIVABLE_KINDS])
    normal = face_cross(mesh.vertices, mesh.faces)[drivable]
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    assert normal[:, 2].min() > 0.0  # up
    # and not steep, except junction faces bridging connecting roads that disagree in height (Town07)
    steep = normal[:, 2] < 0.8
    assert np.all(mesh.kind[drivable][steep] == KIND_CODE["junction"])
    assert np.all(np.isfinite(mesh.vertices)) and np.all(np.isfinite(mesh.uv))
    assert mesh.road_index.min() >= 0 and mesh.road_index.max() < len(odr.roads)
