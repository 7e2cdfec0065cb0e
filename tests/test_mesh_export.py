"""Export: tiled glb / OBJ+MTL load back with the expected triangles, axes, origin; the mapkit mesh command."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh
from click.testing import CliRunner

from tavf_mapkit.cli.main import cli
from tavf_mapkit.mesh import build_road_surface, road_marks
from tavf_mapkit.mesh.export import ExportLayers, export_meshes, from_file_axes, to_file_axes
from tavf_mapkit.opendrive import load_opendrive
from tests.conftest import shared_path


@pytest.fixture(scope="module")
def fabriksgatan():
    odr = load_opendrive(shared_path("xodr", "esmini", "fabriksgatan.xodr"))
    surface = build_road_surface(odr, 0.05)
    return odr, surface, road_marks(odr, 0.05, surface.samples)


def test_axes_are_a_rotation_and_round_trip():
    points = np.array([[10.0, 20.0, 3.0], [-5.0, 7.0, 0.5]])
    origin = (1.0, 2.0, 0.0)
    gltf = to_file_axes(points, origin)
    np.testing.assert_allclose(gltf[0], [9.0, 3.0, -18.0])
    np.testing.assert_allclose(from_file_axes(gltf, origin), points, atol=1e-5)
    # counter-clockwise seen from above stays counter-clockwise seen from glTF's +Y
    triangle = to_file_axes(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0.0]]), (0, 0, 0))
    normal = np.cross(triangle[1] - triangle[0], triangle[2] - triangle[0])
    assert normal[1] > 0


def test_glb_tiles_load_back_with_expected_triangles(fabriksgatan, tmp_path):
    _odr, surface, marks = fabriksgatan
    summary = export_meshes(ExportLayers(surface.mesh, marks), tmp_path, "glb", tile_size=25.0)
    written = json.loads((tmp_path / "mesh.json").read_text())
    assert written == json.loads(json.dumps(summary))
    assert len(summary["tiles"]) > 1
    total = 0
    for tile in summary["tiles"]:
        scene = trimesh.load(tmp_path / tile["file"], force="scene")
        counts = {"lanes": 0, "marks": 0, "solids": 0}
        for name, geometry in scene.geometry.items():
            counts[name.split("_")[0]] += len(geometry.faces)
            assert geometry.visual.material.name == name  # layer_material, e.g. lanes_driving
        assert counts == tile["triangles"]
        total += sum(counts.values())
    assert total == len(surface.mesh.faces) + len(marks.faces) == summary["triangles"]["total"]
    # coordinates: back through the documented transform onto the OpenDRIVE vertices
    origin = tuple(summary["origin"][k] for k in "xyz")
    tile = next(t for t in summary["tiles"] if t["triangles"]["lanes"])
    scene = trimesh.load(tmp_path / tile["file"], force="scene")
    geometry = next(g for name, g in scene.geometry.items() if name.startswith("lanes"))
    back = from_file_axes(geometry.vertices, origin)
    # every exported vertex is a vertex of the mesh (float32 rounding: well below a millimetre)
    distance = np.min(np.linalg.norm(back[:, None, :] - surface.mesh.vertices[None, :, :], axis=2), axis=1)
    assert distance.max() < 1e-4
    # and lies in (or, for triangles whose centre is inside, near) its tile
    west, south, east, north = tile["bounds"]
    centre = back[geometry.faces].mean(axis=1)
    assert np.all((centre[:, 0] >= west - 1e-3) & (centre[:, 0] <= east + 1e-3))
    assert np.all((centre[:, 1] >= south - 1e-3) & (centre[:, 1] <= north + 1e-3))
    assert (tmp_path / "preview.png").stat().st_size > 1000
    materials = set(summary["materials"])
    assert {"driving", "sidewalk", "roadmark_white"} <= materials


def test_obj_tiles_load_in_trimesh_and_pybullet(fabriksgatan, tmp_path):
    import pybullet

    _odr, surface, marks = fabriksgatan
    summary = export_meshes(ExportLayers(surface.mesh, marks), tmp_path, "obj", tile_size=5000.0, preview=False)
    assert len(summary["tiles"]) == 1 and not (tmp_path / "preview.png").exists()
    path = tmp_path / summary["tiles"][0]["file"]
    assert (tmp_path / "tiles" / "materials.mtl").read_text().count("newmtl") == len(summary["materials"])
    loaded = trimesh.load(path, force="mesh", process=False)
    assert len(loaded.faces) == summary["triangles"]["total"]
    client = pybullet.connect(pybullet.DIRECT)
    try:
        shape = pybullet.createCollisionShape(pybullet.GEOM_MESH, fileName=str(path),
                                              flags=pybullet.GEOM_FORCE_CONCAVE_TRIMESH, physicsClientId=client)
        assert shape >= 0
    finally:
        pybullet.disconnect(client)


def test_mesh_command(tmp_path):
    xodr = shared_path("xodr", "esmini", "multi_intersections.xodr")
    out = tmp_path / "mesh"
    result = CliRunner().invoke(cli, ["mesh", str(xodr), "-o", str(out), "--eps", "0.1", "--tile", "50",
                                      "--no-solids", "--json"])
    assert result.exit_code == 0, result.output
    report = json.loads(result.output)
    assert report["eps"] == 0.1 and report["tile_size"] == 50.0 and report["solids"] is False
    assert report["deviation"]["max_m"] <= 0.1
    assert report["triangles"]["junctions"] > 0
    assert len(list((out / "tiles").glob("*.glb"))) == report["tiles"]
    # an earlier mesh folder is replaced; text output names the numbers
    result = CliRunner().invoke(cli, ["mesh", str(xodr), "-o", str(out), "--format", "obj", "--no-solids"])
    assert result.exit_code == 0, result.output
    assert "deviation  <=" in result.output
    assert not list((out / "tiles").glob("*.glb")) and list((out / "tiles").glob("*.obj"))


def test_mesh_command_errors(tmp_path):
    runner = CliRunner()
    bad = tmp_path / "bad.xodr"
    bad.write_text("<OpenDRIVE><road")
    result = runner.invoke(cli, ["mesh", str(bad), "-o", str(tmp_path / "out")])
    assert result.exit_code == 2
    assert result.output.count("\n") == 1 and "bad.xodr" in result.output and "Traceback" not in result.output
    assert not (tmp_path / "out").exists()
    keep = tmp_path / "precious"
    keep.mkdir()
    (keep / "thesis.tex").write_text("do not delete")
    xodr = shared_path("xodr", "esmini", "straight_500m.xodr")
    result = runner.invoke(cli, ["mesh", str(xodr), "-o", str(keep)])
    assert result.exit_code == 2 and "holds no mesh.json" in result.output
    assert (keep / "thesis.tex").read_text() == "do not delete"
    result = runner.invoke(cli, ["mesh", str(xodr), "-o", str(tmp_path / "x"), "--eps", "0"])
    assert result.exit_code == 2 and "--eps" in result.output
    assert not [p for p in tmp_path.iterdir() if ".staging-" in p.name]
