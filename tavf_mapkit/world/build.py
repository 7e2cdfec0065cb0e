"""Build the pybullet collision world of a map: collision/world.json plus one OBJ per body, tile by tile on
the build's tile grid (``tavf_mapkit.tilegrid``), the exported meshes' squares and names.

Bodies are static concave triangle meshes, one per tile and group:
- ``road``: drivable road surface (driving, biking, parking, shoulder, restricted lanes and junction surfaces)
- ``roadside``: the rest of the road surface (sidewalks, borders, medians, curb faces, ...)
- ``curb``, ``object``, ``signal``, ``building``: the scene solids (each solid whole, in the tile of its centre)

pybullet works in float32, so every coordinate is written relative to ``origin`` -- the OpenDRIVE local
coordinates of the pybullet world's (0, 0, 0): pybullet = local - origin.
"""

from __future__ import annotations

import hashlib
import json
import os
import zipfile
from pathlib import Path

import numpy as np

from tavf_mapkit.fileutil import StagedFolder
from tavf_mapkit.mesh.kinds import DRIVABLE_KINDS
from tavf_mapkit.mesh.labelled import KIND_CODE, SURFACE_KINDS, LabelledMesh
from tavf_mapkit.mesh.tiles import face_tiles, map_origin, solid_tiles
from tavf_mapkit.progress import Progress, reporter
from tavf_mapkit.tilegrid import TileGrid, group_by_tile
from tavf_mapkit.world.objfile import obj_text
from tavf_mapkit.world.parts import BodyPart, tile_body_parts

FORMAT = "tavf-mapkit collision world"
FORMAT_VERSION = 1
GROUPS = ("road", "roadside", "curb", "object", "signal", "building")
SOLID_GROUPS = ("curb", "object", "signal", "building")


def tile_bodies(index: tuple[int, int], surface: LabelledMesh | None, solids) -> list[BodyPart]:
    """The bodies of one tile, ordered by group and name: its road-surface faces (by centroid) as ``road``
    and ``roadside``, its solids (whole, by centre) one body per group."""
    index = (int(index[0]), int(index[1]))
    parts = []
    if surface is not None and len(surface.faces):
        drivable = _DRIVABLE_CODE[surface.kind]
        for group, mask in (("road", drivable), ("roadside", ~drivable)):
            if np.any(mask):
                parts.extend(tile_body_parts(surface.select(mask), index, group))
    for group in SOLID_GROUPS:
        members = [solid for solid in solids if solid.kind == group]
        if members:
            mesh = LabelledMesh.concatenate([solid.mesh for solid in members])
            if len(mesh.faces):
                # select drops the vertices no face uses (a solid's mesh may keep some)
                parts.extend(tile_body_parts(mesh.select(slice(None)), index, group))
    rank = {group: k for k, group in enumerate(GROUPS)}
    return sorted(parts, key=lambda p: (rank[p.group], p.name))


#: drivable or not, by surface kind code (a table lookup: np.isin per tile was a tenth of the stage's time)
_DRIVABLE_CODE = np.isin(np.arange(len(SURFACE_KINDS)), [KIND_CODE[k] for k in DRIVABLE_KINDS])


def _kind_counts(mesh: LabelledMesh) -> dict[str, int]:
    counts = np.bincount(mesh.kind.astype(np.int64), minlength=len(SURFACE_KINDS))
    return {SURFACE_KINDS[k]: int(c) for k, c in enumerate(counts) if c}


def build_collision_world(odr, out_dir, eps: float = 0.05, osm_path: Path | None = None, tile: float = 100.0,
                          surface: LabelledMesh | None = None, origin=None, scene=None) -> dict:
    """Write ``out_dir/collision/`` (world.json and tiles/*.obj) and return the content of world.json.

    ``surface`` is the road-surface mesh (``tavf_mapkit.mesh.road_surface(odr, eps)`` when not given);
    ``osm_path`` the OSM input whose buildings are added; ``origin`` the recentring origin (x, y, z) -- pass
    the exported meshes' origin (mesh/mesh.json) so visual and collision world line up; by default the
    mesh exporter's rule (``mesh.tiles.map_origin``: whole metres at the middle of the plan bounds, z = 0);
    ``scene`` the scene solids (``mesh.solids.SceneSolids``) when already made from the same surface and input.
    The whole map is held in memory; a build streams the mesh stage's labelled tiles instead
    (``build_collision_world_from_tiles``), with the same result.
    """
    from tavf_mapkit.mesh.solids import scene_solid_parts

    _check_options(eps, tile)
    if surface is None:
        from tavf_mapkit.mesh import road_surface

        surface = road_surface(odr, eps=eps)
    if scene is None:
        scene = scene_solid_parts(odr, surface, osm_path, eps)
    if origin is None:
        origin = map_origin([surface, scene.mesh()])
    grid = TileGrid(tuple(_origin(origin)), float(tile))
    faces_of = group_by_tile(face_tiles(grid, surface))
    solids_of = group_by_tile(solid_tiles(grid, [s.mesh for s in scene.solids]))
    writer = _WorldWriter(out_dir, grid, eps, world_georeference(odr.header))
    try:
        for index in sorted(set(faces_of) | set(solids_of), key=lambda t: (t[1], t[0])):
            part = surface.select(faces_of[index]) if index in faces_of else None
            writer.add(index, tile_bodies(index, part, [scene.solids[k] for k in solids_of.get(index, [])]))
        return writer.finish({**scene.counts(), "skipped": list(scene.skipped)})
    except BaseException:
        writer.abandon()
        raise


def build_collision_world_from_tiles(labelled: Path, out_dir, progress: Progress | None = None,
                                    fanout=None) -> dict:
    """``build_collision_world`` from labelled tiles (``mesh.tiled``: mesh/labelled of a build), one tile at a
    time: the memory of a tile, not of the map. The world takes their eps, grid, origin and georeference.
    ``progress`` hears of the tiles done. ``fanout``: a ``cluster.Fanout`` that makes the tiles' bodies as Dask
    tasks (each gets its labelled tiles' bytes and sends back OBJ files; the world comes out the same).
    ``UnreadableTile`` (and no collision/ written) when a labelled tile cannot be read."""
    from tavf_mapkit.mesh.tiled import read_labelled_index

    index_json = read_labelled_index(labelled)
    eps, tile = float(index_json["eps"]), float(index_json["tile_size"])
    _check_options(eps, tile)
    grid = TileGrid(tuple(_origin(index_json["origin"])), tile)
    writer = _WorldWriter(out_dir, grid, eps, index_json["georeference"])
    try:
        report = reporter(progress, "tiles")
        tiles = sorted(zip(index_json["tiles"], map(tuple, index_json["indices"])),
                       key=lambda item: (item[1][1], item[1][0]))
        if fanout is None:
            made = (tile_files(grid, index, f"{labelled}/{name}.npz") for name, index in tiles)
        else:
            from tavf_mapkit.world.remote import remote_tile_files

            made = remote_tile_files(fanout, grid, labelled, tiles)
        report(0, len(tiles))
        for done, ((_, index), files) in enumerate(zip(tiles, made), 1):
            writer.put(index, files)
            report(done, len(tiles))
        return writer.finish({**index_json["solid_counts"], "skipped": list(index_json["skipped"])})
    except BaseException:
        writer.abandon()
        raise


class UnreadableTile(Exception):
    """A labelled tile that cannot be read (missing, truncated, not a zip of arrays): whoever offered the tiles
    makes the world another way (the collision stage meshes the map itself)."""


#: what reading a damaged labelled tile raises (zip: BadZipFile; arrays: EOFError / ValueError; parts: KeyError ...)
TILE_READ_ERRORS = (OSError, ValueError, KeyError, TypeError, IndexError, EOFError, zipfile.BadZipFile)


def tile_files(grid: TileGrid, index, labelled_tile) -> list[tuple[str, bytes, dict]]:
    """The body files of one tile from its labelled tile (a path or the file's bytes); ``UnreadableTile`` when
    the tile cannot be read. Each tile is read once: checking them all before the build read them twice."""
    from tavf_mapkit.mesh.tiled import read_labelled_tile

    try:
        surface, scene = read_labelled_tile(labelled_tile)
    except TILE_READ_ERRORS as error:
        where = labelled_tile if not isinstance(labelled_tile, bytes) else f"tile {tuple(index)}"
        raise UnreadableTile(f"{where}: {error}") from None
    return body_files(np.asarray(grid.origin, dtype=np.float64), tile_bodies(index, surface, scene.solids))


def body_files(origin: np.ndarray, parts: list[BodyPart]) -> list[tuple[str, bytes, dict]]:
    """(path in collision/, OBJ bytes, world.json body record) of every body, coordinates relative to origin."""
    out = []
    for part in parts:
        relative = f"tiles/{part.name}.obj"
        local = part.mesh.vertices - origin
        data = obj_text(part.name, local, part.mesh.faces,
                        f"{FORMAT}: {part.group} of {part.tile}, metres, pybullet = OpenDRIVE local - origin"
                        ).encode("ascii")
        out.append((relative, data, {
            "name": part.name, "tile": part.tile, "group": part.group, "file": relative,
            "sha256": hashlib.sha256(data).hexdigest(),
            "vertices": len(part.mesh.vertices), "triangles": len(part.mesh.faces),
            "kinds": _kind_counts(part.mesh),
            "bounds": [np.round(local.min(axis=0), 4).tolist(), np.round(local.max(axis=0), 4).tolist()],
        }))
    return out


def world_georeference(header) -> dict:
    """world.json's georeference: the header's PROJ string and offset."""
    return {"proj": header.geo_reference,
            "offset": None if header.offset is None else {
                "x": header.offset.x, "y": header.offset.y, "z": header.offset.z, "hdg": header.offset.hdg}}


def _check_options(eps: float, tile: float) -> None:
    if not (eps > 0 and np.isfinite(eps)):
        raise ValueError("eps must be a positive number of metres")
    if not (tile > 0 and np.isfinite(tile)):
        raise ValueError("tile must be a positive number of metres")


def _origin(origin) -> np.ndarray:
    origin = np.asarray(origin, dtype=np.float64).reshape(3) + 0.0
    if not np.all(np.isfinite(origin)):
        raise ValueError("origin must be three finite numbers")
    return origin


class _WorldWriter:
    """collision/ written tile by tile into a staging folder, put in place whole at the end."""

    def __init__(self, out_dir, grid: TileGrid, eps: float, georeference: dict):
        self.grid, self.eps, self.georeference = grid, eps, georeference
        self.origin = np.asarray(grid.origin, dtype=np.float64)
        self.folder = StagedFolder(Path(out_dir) / "collision", what="the collision world").open()
        self.staging = self.folder.staging
        (self.staging / "tiles").mkdir()
        self.bodies, self.tiles = [], {}

    def add(self, index, parts: list[BodyPart]) -> None:
        self.put(index, body_files(self.origin, parts))

    def put(self, index, files: list[tuple[str, bytes, dict]]) -> None:
        """Files of a tile's bodies (``body_files``) written, their records kept for world.json."""
        for relative, data, body in files:
            _write_new_file(f"{self.staging}/{relative}", data)
            self.bodies.append(body)
            entry = self.tiles.setdefault(body["tile"], {
                "name": body["tile"], "index": list(index), "bounds": self.grid.relative_bounds(index),
                "bodies": []})
            entry["bodies"].append(body["name"])

    def finish(self, solids: dict) -> dict:
        world = {
            "format": FORMAT, "version": FORMAT_VERSION,
            "origin": self.origin.tolist(),
            "frame": "x east, y north, z up, metres (OpenDRIVE local axes); pybullet = OpenDRIVE local - origin",
            "eps": self.eps, "tile_size": self.grid.size,
            "georeference": self.georeference,
            "groups": {"road": list(DRIVABLE_KINDS), "roadside": "other road-surface kinds",
                       "curb": "solids", "object": "solids", "signal": "solids", "building": "solids"},
            "tiles": list(self.tiles.values()),
            "bodies": self.bodies,
            "solids": solids,
            "totals": {"tiles": len(self.tiles), "bodies": len(self.bodies),
                       "vertices": int(sum(b["vertices"] for b in self.bodies)),
                       "triangles": int(sum(b["triangles"] for b in self.bodies))},
        }
        (self.staging / "world.json").write_text(json.dumps(world, indent=1) + "\n", encoding="utf-8")
        self.folder.commit()
        return world

    def abandon(self) -> None:
        self.folder.discard()


def _write_new_file(path: str, data: bytes) -> None:
    """``Path(path).write_bytes(data)`` with os calls: the pathlib and io layers were a third of writing a
    region's tens of thousands of small OBJ files."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | getattr(os, "O_BINARY", 0), 0o666)
    try:
        view = memoryview(data)
        while view:
            view = view[os.write(fd, view):]
    finally:
        os.close(fd)
