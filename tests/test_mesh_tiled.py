"""The tiled mesher (mesh/tiled.py): batches of any size give the same files, those files are the whole map's
meshes exported at once, the collision world cut from its labelled tiles is the world made from the whole map,
and its memory grows with the batch and the tile, not with the map."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tavf_mapkit.mesh.export import ExportLayers, export_meshes
from tavf_mapkit.mesh.folder import write_mesh_folder
from tavf_mapkit.mesh.labelled import KIND_CODE
from tavf_mapkit.mesh.marks import road_marks
from tavf_mapkit.mesh.solids import scene_solid_parts
from tavf_mapkit.mesh.surface import build_road_surface
from tavf_mapkit.mesh.tiled import read_labelled_index, read_labelled_tile
from tavf_mapkit.mesh.tiles import face_tiles
from tavf_mapkit.tilegrid import TileGrid
from tavf_mapkit.mesh.units import mesh_units
from tavf_mapkit.opendrive import load_opendrive
from tavf_mapkit.world import build_collision_world
from tavf_mapkit.world.build import build_collision_world_from_tiles

from tests.xodr_factory import tiled_copies

REPO = Path(__file__).resolve().parents[1]


def files(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def build_inputs(folder: Path):
    return folder / f"{folder.name}.xodr", folder / "source" / f"{folder.name}.osm"


@pytest.fixture(params=["sample_build_dir", "jungfernstieg_build"])
def built(request):
    return build_inputs(request.getfixturevalue(request.param))


def test_batches_of_any_size_give_the_same_files(built, tmp_path):
    xodr, osm = built
    odr = load_opendrive(xodr)
    units = mesh_units(odr)
    spill = TileGrid.spill(100.0)
    assert len(units.batches(spill, 1e12)) == 1 and len(units.batches(spill, 300.0)) >= 8
    assert sum(1 for junctions in units.unit_junctions if junctions) >= 5  # junction clusters among the units
    one = write_mesh_folder(odr, tmp_path / "one", osm_path=osm, batch_work=1e12)
    many = write_mesh_folder(odr, tmp_path / "many", osm_path=osm, batch_work=300.0)
    assert one == many
    a, b = files(tmp_path / "one"), files(tmp_path / "many")
    assert list(a) == list(b) and not [name for name in a if a[name] != b[name]]
    assert one["triangles"]["junctions"] > 0 and one["triangles"]["solids"] > 0 and one["triangles"]["marks"] > 0
    assert not [p for p in (tmp_path / "one").iterdir() if p.name.startswith(".")]  # no spill left


def test_a_batch_evaluates_only_its_own_geometries_and_breaks_alike(sample_build_dir):
    """A batch's breakpoints are those of the whole map's sections it meshes, found from its own geometries'
    joints alone (a city has 5 million arcs and lines: evaluating them all for every batch took 0.8 GB each)."""
    from tavf_mapkit.mesh.adaptive import initial_breaks, smooth_geometry_starts

    xodr, _ = build_inputs(sample_build_dir)
    arrays = load_opendrive(xodr).arrays
    table = arrays.geometries
    whole = smooth_geometry_starts(table)
    rows = np.flatnonzero(np.arange(len(table)) % 3 != 1)
    assert np.array_equal(smooth_geometry_starts(table, rows), whole[rows]) and whole.any() and not whole.all()
    every = initial_breaks(arrays, 25.0)
    roads = np.unique(arrays.section_road)[::4]
    only = np.flatnonzero(np.isin(arrays.section_road, roads))
    mine = np.isin(every[0], only)
    assert all(np.array_equal(part, full[mine]) for part, full in zip(initial_breaks(arrays, 25.0, only), every))


def test_tile_caches_of_any_size_give_the_same_files(sample_build_dir, tmp_path, monkeypatch):
    """The merged spill tiles are cached by bytes (a freeway interchange's tiles are megabytes): a cache that
    holds one tile at a time merges tiles again and again, and writes the same files."""
    from tavf_mapkit.mesh import tiled

    xodr, osm = build_inputs(sample_build_dir)
    odr = load_opendrive(xodr)
    reads = []
    original = tiled.ChunkStore.get
    monkeypatch.setattr(tiled.ChunkStore, "get", lambda store, key: reads.append(key) or original(store, key))
    roomy = write_mesh_folder(odr, tmp_path / "roomy", osm_path=osm)
    roomy_reads = len(reads)
    monkeypatch.setattr(tiled, "TILE_CACHE_BYTES", 1)
    tight = write_mesh_folder(odr, tmp_path / "tight", osm_path=osm)
    assert roomy == tight
    a, b = files(tmp_path / "roomy"), files(tmp_path / "tight")
    assert list(a) == list(b) and not [name for name in a if a[name] != b[name]]
    assert len(reads) - roomy_reads > 2 * roomy_reads  # spill tiles were read again: the cache held one at a time


def test_the_tiles_are_the_whole_maps_meshes_exported_at_once(built, tmp_path):
    xodr, osm = built
    odr = load_opendrive(xodr)
    tiled = write_mesh_folder(odr, tmp_path / "tiled", osm_path=osm, batch_work=500.0)
    units = mesh_units(odr)
    surface = build_road_surface(odr, 0.05, units=units)
    marks = road_marks(odr, 0.05, surface.samples)
    scene = scene_solid_parts(odr, surface.mesh, osm, 0.05)
    whole = export_meshes(ExportLayers(surface.mesh, marks.grouped(units.road_unit[marks.road_index]),
                                       scene.mesh(), {}), tmp_path / "whole", "glb", 100.0)
    assert whole["tiles"] == tiled["tiles"] and whole["origin"] == tiled["origin"]
    assert whole["triangles"] == tiled["triangles"]
    for entry in tiled["tiles"]:
        assert (tmp_path / "tiled" / entry["file"]).read_bytes() == (tmp_path / "whole" / entry["file"]).read_bytes()
    assert (tmp_path / "tiled" / "preview.png").read_bytes() == (tmp_path / "whole" / "preview.png").read_bytes()

    # labelled tiles: every surface face once, in the tile of its centroid; every solid once, by its centre
    index = read_labelled_index(tmp_path / "tiled" / "labelled")
    grid = TileGrid.of(index)
    faces, solids = 0, []
    for name, tile in zip(index["tiles"], index["indices"]):
        part, tile_scene = read_labelled_tile(tmp_path / "tiled" / "labelled" / f"{name}.npz")
        if part is not None:
            assert np.all(face_tiles(grid, part) == tile)
            faces += len(part.faces)
        solids += [solid.source for solid in tile_scene.solids]
    assert faces == len(surface.mesh.faces) and sorted(solids) == sorted(s.source for s in scene.solids)
    assert index["skipped"] == list(scene.skipped)

    # the collision world from the labelled tiles is the one made from the whole map
    origin = [tiled["origin"][k] for k in "xyz"]
    streamed = build_collision_world_from_tiles(tmp_path / "tiled" / "labelled", tmp_path / "a")
    made = build_collision_world(odr, tmp_path / "b", eps=0.05, osm_path=osm, tile=100.0, surface=surface.mesh,
                                 origin=origin, scene=scene)
    assert streamed == made
    assert files(tmp_path / "a" / "collision") == files(tmp_path / "b" / "collision")


def test_collision_tiles_are_the_mesh_tiles(sample_build_dir):
    """One grid: every collision body lies in the mesh tile of the same name (squares centred on the origin)."""
    mesh = json.loads((sample_build_dir / "mesh" / "mesh.json").read_text())
    world = json.loads((sample_build_dir / "collision" / "world.json").read_text())
    assert world["origin"] == [mesh["origin"][k] for k in "xyz"] and world["tile_size"] == mesh["tile_size"]
    bounds = {Path(entry["file"]).stem: entry["bounds"] for entry in mesh["tiles"]}
    origin = np.array(world["origin"][:2])
    road = [tile for tile in world["tiles"] if any(name.endswith("_road") for name in tile["bodies"])]
    assert road
    for tile in road:
        west, south, east, north = bounds[tile["name"]]
        assert np.allclose(tile["bounds"], [west - origin[0], south - origin[1], east - origin[0], north - origin[1]])


def test_junction_surfaces_of_a_cluster_do_not_depend_on_other_clusters(sample_build_dir):
    xodr, _ = build_inputs(sample_build_dir)
    odr = load_opendrive(xodr)
    units = mesh_units(odr)
    whole = build_road_surface(odr, 0.05, units=units).mesh
    cluster = next(u for u, junctions in enumerate(units.unit_junctions) if junctions)
    alone = build_road_surface(odr, 0.05, units=units, roads=units.roads_of(cluster)).mesh
    mine = np.flatnonzero(units.road_unit[whole.road_index] == cluster)
    part = whole.select(mine)
    assert np.any(alone.kind == KIND_CODE["junction"])
    for name in ("vertices", "faces", "road_index", "lane_id", "kind", "uv"):
        assert np.array_equal(getattr(part, name), getattr(alone, name)), name


CHILD = r"""
import json, resource, sys
from tavf_mapkit.opendrive import load_opendrive
odr = load_opendrive(sys.argv[1])
_ = odr.arrays
if sys.argv[2] == "mesh":
    from tavf_mapkit.mesh.folder import write_mesh_folder
    write_mesh_folder(odr, sys.argv[3], 0.05, batch_work=float(sys.argv[4]), preview=True)
print(json.dumps({"peak_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, "roads": len(odr.roads)}))
"""


def _peak(xodr: Path, mode: str, out: Path, batch_work: float) -> dict:
    result = subprocess.run([sys.executable, "-c", CHILD, str(xodr), mode, str(out), str(batch_work)],
                            capture_output=True, text=True, timeout=900, cwd=REPO)
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout.strip().splitlines()[-1])


@pytest.mark.slow
def test_mesh_memory_grows_with_the_batch_not_with_the_map(sample_build_dir, tmp_path):
    """The sample map side by side 2 x 2 and 5 x 5 times (6.25 x the roads): what meshing adds to the loaded map's
    peak memory stays about the same, where meshing the whole map at once would need 6 x as much."""
    xodr, _ = build_inputs(sample_build_dir)
    text = xodr.read_text(encoding="utf-8")
    extra = {}
    for n in (2, 5):
        path = tmp_path / f"copies{n}.xodr"
        path.write_text(tiled_copies(text, n, n, 1000.0), encoding="utf-8")
        loaded = _peak(path, "load", tmp_path / f"out{n}", 0)
        meshed = _peak(path, "mesh", tmp_path / f"out{n}", 20_000.0)
        extra[n] = (meshed["peak_mib"] - loaded["peak_mib"], loaded["roads"])
    (small, small_roads), (large, large_roads) = extra[2], extra[5]
    assert 4 * large_roads == 25 * small_roads
    assert large < 1.5 * small + 40.0, extra
