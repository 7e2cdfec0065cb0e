"""The mesh stage in real builds (sample district, both Hamburg inputs) and netconvert's TAVF OpenDRIVE."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from tavf_mapkit.mesh import KIND_CODE, build_road_surface, road_marks
from tavf_mapkit.mesh.cleanup import face_cross, triangle_areas
from tavf_mapkit.mesh.kinds import DRIVABLE_KINDS
from tavf_mapkit.mesh.measure import distance_to_mesh
from tavf_mapkit.opendrive import load_opendrive
from tavf_mapkit.opendrive.sampling import sample_lane_borders


def _check_build(build):
    manifest = json.loads((build / "manifest.json").read_text())
    stage = next(s for s in manifest["stages"] if s["name"] == "mesh")
    assert stage["status"] in ("ran", "unchanged"), stage
    summary = json.loads((build / "mesh" / "mesh.json").read_text())
    assert (build / "report" / "mesh_preview.png").read_bytes() == (build / "mesh" / "preview.png").read_bytes()
    assert summary["eps"] == 0.05 and summary["deviation"]["max_m"] <= 0.05
    total = 0
    for tile in summary["tiles"]:
        scene = trimesh.load(build / "mesh" / tile["file"], force="scene")
        count = sum(len(g.faces) for g in scene.geometry.values())
        assert count == sum(tile["triangles"].values())
        total += count
    assert total == summary["triangles"]["total"]
    assert stage["facts"]["triangles"] == summary["triangles"]
    # the mesh itself: normals up, no degenerate triangles
    odr = load_opendrive(next(build.glob("*.xodr")))
    mesh = build_road_surface(odr, 0.05).mesh
    assert triangle_areas(mesh.vertices, mesh.faces).min() >= 1e-8
    drivable = np.isin(mesh.kind, [KIND_CODE[k] for k in DRIVABLE_KINDS])
    assert np.all(face_cross(mesh.vertices, mesh.faces)[drivable, 2] > 0)
    assert summary["triangles"]["lanes"] + summary["triangles"]["junctions"] + summary["triangles"]["curb_faces"] \
        == len(mesh.faces)
    return summary


def test_sample_build_has_meshes(sample_build_dir):
    summary = _check_build(sample_build_dir)
    assert summary["junctions"] > 0


@pytest.mark.slow
def test_jungfernstieg_build_has_meshes(jungfernstieg_build):
    summary = _check_build(jungfernstieg_build)
    assert summary["triangles"]["marks"] > 0 and len(summary["tiles"]) > 10


@pytest.mark.slow
def test_tavf_dlr_build_has_meshes(tavf_dlr_build):
    summary = _check_build(tavf_dlr_build)
    assert summary["junctions"] > 100


@pytest.mark.slow
@pytest.mark.parametrize("eps", [0.1, 0.05])
def test_netconvert_tavf_opendrive_within_eps(tavf_xodr, eps):
    odr = load_opendrive(tavf_xodr)
    surface = build_road_surface(odr, eps)
    marks = road_marks(odr, eps, surface.samples)
    mesh = surface.mesh
    borders = sample_lane_borders(odr, 0.5)
    points = np.column_stack([borders.x, borders.y, borders.z])
    junction = np.array([road.in_junction for road in odr.roads])[borders.road]
    distance = distance_to_mesh(mesh.vertices, mesh.faces, points[~junction], search_radius=0.5)
    assert distance.max() <= eps + 1e-3
    # fewer triangles than an independent C++ mesher needs for this file at eps 0.1
    if eps == 0.1:
        assert len(mesh.faces) < 64_686 and len(marks.faces) < 65_846
    assert triangle_areas(mesh.vertices, mesh.faces).min() >= 1e-8
    assert np.all(face_cross(marks.vertices, marks.faces)[:, 2] > 0)
