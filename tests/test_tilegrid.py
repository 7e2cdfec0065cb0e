"""One tile grid (tavf_mapkit/tilegrid.py): the mesh files, the collision world, the report and the twin give a
point the same tile, with the same name and the same square."""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np
import pybullet
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tavf_mapkit.mesh.export import ExportLayers, export_meshes
from tavf_mapkit.mesh.labelled import KIND_CODE, LabelledMesh
from tavf_mapkit.mesh.solids import SceneSolids
from tavf_mapkit.mesh.tiles import face_centroids
from tavf_mapkit.opendrive import load_opendrive
from tavf_mapkit.tilegrid import TileGrid, tile_index, tile_name
from tavf_mapkit.world import build_collision_world, load

coordinate = st.floats(-20_000, 20_000, allow_nan=False)


@pytest.fixture(scope="module")
def sample_odr(sample_build_dir):
    return load_opendrive(sample_build_dir / "sample.xodr")


@pytest.fixture(scope="module")
def sample_files(sample_build_dir):
    mesh = json.loads((sample_build_dir / "mesh" / "mesh.json").read_text())
    world = json.loads((sample_build_dir / "collision" / "world.json").read_text())
    return mesh, world


@pytest.fixture(scope="module")
def loaded_world(sample_build_dir):
    """The sample build's collision world as the twin loads it."""
    client = pybullet.connect(pybullet.DIRECT)
    yield load(sample_build_dir, client)
    pybullet.disconnect(client)


def test_squares_names_and_edges():
    grid = TileGrid((10.0, -20.0, 0.0), 100.0)
    assert grid.tile_of_point(10.0, -20.0) == (0, 0) and grid.tile_bounds((0, 0)) == [-40.0, -70.0, 60.0, 30.0]
    # a point on a west or south edge belongs to that tile, on an east or north edge to the next one
    assert grid.tile_of_point(-40.0, -70.0) == (0, 0) and grid.tile_of_point(60.0, 30.0) == (1, 1)
    assert grid.relative_bounds((-1, 2)) == [-150.0, 150.0, -50.0, 250.0]
    assert tile_name((-1, 2)) == "tile_-1_+2" and tile_index("tile_-1_+2") == (-1, 2)
    with pytest.raises(ValueError, match="not a tile name: 'tile_1_2'"):
        tile_index("tile_1_2")
    with pytest.raises(ValueError, match="tile size must be a positive number of metres"):
        TileGrid((0.0, 0.0, 0.0), 0.0)
    # the mesher's spill grid: the same kind of squares, a corner at local (0, 0)
    assert TileGrid.spill(50.0).tile_bounds((0, 0)) == [0.0, 0.0, 50.0, 50.0]
    assert TileGrid.spill(50.0).tile_of_point(-0.001, 49.999) == (-1, 0)
    # a box belongs to the tile of its centre
    assert grid.tile_of_boxes(np.array([[50.0, 0.0]]), np.array([[80.0, 10.0]])).tolist() == [[1, 0]]


@settings(max_examples=30, deadline=None)
@given(x=coordinate, y=coordinate, size=st.sampled_from([7.5, 25.0, 100.0, 333.0]),
       ox=st.integers(-5000, 5000), oy=st.integers(-5000, 5000))
def test_a_face_goes_to_the_mesh_tile_and_the_collision_tile_of_the_same_name(sample_odr, x, y, size, ox, oy):
    """Through the real writers: the file a face is exported into and the collision body it is cut into are
    named for one tile, whose square (as each file records it) holds the face's centroid."""
    triangle = LabelledMesh(np.array([[x - 0.3, y - 0.2, 0.0], [x + 0.4, y - 0.1, 0.0], [x, y + 0.5, 0.0]]),
                            np.array([[0, 1, 2]]), np.zeros(1, np.int32), np.full(1, -1, np.int32),
                            np.full(1, KIND_CODE["driving"], np.int16))
    origin = (float(ox), float(oy), 0.0)
    with tempfile.TemporaryDirectory() as scratch:
        mesh = export_meshes(ExportLayers(triangle), Path(scratch) / "mesh", "obj", tile_size=size, origin=origin,
                             preview=False)
        world = build_collision_world(sample_odr, Path(scratch), eps=0.05, tile=size, surface=triangle,
                                      origin=origin, scene=SceneSolids((), ()))
    [entry], [body], [tile] = mesh["tiles"], world["bodies"], world["tiles"]
    name = Path(entry["file"]).stem
    assert name == body["tile"] == tile["name"] == tile_name(entry["index"]) == tile_name(tile["index"])
    centroid = face_centroids(triangle)[0, :2]
    west, south, east, north = entry["bounds"]
    assert west <= centroid[0] < east and south <= centroid[1] < north
    assert np.allclose(tile["bounds"], [west - ox, south - oy, east - ox, north - oy])
    assert TileGrid.of(mesh) == TileGrid.of(world)


@settings(max_examples=200, deadline=None)
@given(u=st.floats(-1.5, 1.5), v=st.floats(-1.5, 1.5))
def test_mesh_collision_report_and_twin_name_a_point_alike(sample_files, loaded_world, u, v):
    """Random points over (and around) the sample build: its mesh.json, its world.json and the twin's loaded
    world put each in the same tile, and the recorded squares of that tile hold it."""
    mesh, world = sample_files
    grid = TileGrid.of(mesh)
    low = np.min([entry["bounds"][:2] for entry in mesh["tiles"]], axis=0)
    high = np.max([entry["bounds"][2:] for entry in mesh["tiles"]], axis=0)
    x, y = 0.5 * (low + high) + np.array([u, v]) * 0.5 * (high - low)
    name = grid.name_of_point(x, y)
    assert name == TileGrid.of(world).name_of_point(x, y) == loaded_world.tile_at(x, y)
    mesh_bounds = {Path(entry["file"]).stem: entry["bounds"] for entry in mesh["tiles"]}
    world_bounds = {entry["name"]: entry["bounds"] for entry in world["tiles"]}
    if name in mesh_bounds:
        west, south, east, north = mesh_bounds[name]
        assert west <= x < east and south <= y < north
    if name in world_bounds:
        west, south, east, north = world_bounds[name]
        assert west <= x - grid.origin[0] < east and south <= y - grid.origin[1] < north
    assert (name in world_bounds) == (name in loaded_world.by_tile)


def test_a_builds_mesh_and_collision_tiles_cover_the_same_squares(sample_build_dir, sample_files):
    mesh, world = sample_files
    origin = np.array(world["origin"][:2])
    mesh_squares = {Path(entry["file"]).stem: entry["bounds"] for entry in mesh["tiles"]}
    world_squares = {entry["name"]: entry["bounds"] for entry in world["tiles"]}
    assert len(mesh_squares) >= 20 and world_squares.keys() <= mesh_squares.keys()
    for name, bounds in world_squares.items():
        west, south, east, north = mesh_squares[name]
        assert np.allclose(bounds, [west - origin[0], south - origin[1], east - origin[0], north - origin[1]]), name
    # the road surface is cut by face centroid in both: the same tiles hold it
    surface_in_mesh = {Path(entry["file"]).stem for entry in mesh["tiles"] if entry["triangles"]["lanes"]}
    surface_in_world = {body["tile"] for body in world["bodies"] if body["group"] in ("road", "roadside")}
    assert surface_in_mesh == surface_in_world
    # and the report says so
    report = json.loads((sample_build_dir / "report" / "summary.json").read_text())["tiles"]
    assert report["one_grid"] is True and report["size"] == mesh["tile_size"] == world["tile_size"]
    assert report["mesh"]["tiles"] == len(mesh_squares) and report["collision"]["tiles"] == len(world_squares)
    assert report["origin"] == world["origin"]
    text = (sample_build_dir / "report" / "summary.txt").read_text()
    assert f"tiles   {len(mesh_squares)} mesh + {len(world_squares)} collision tiles of 100 m centred on local" in text
