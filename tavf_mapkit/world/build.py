"""Build the pybullet collision world of a map: collision/world.json plus one OBJ per body.

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
import shutil
import tempfile
from pathlib import Path

import numpy as np

from tavf_mapkit.mesh.kinds import DRIVABLE_KINDS
from tavf_mapkit.mesh.labelled import KIND_CODE, SURFACE_KINDS, LabelledMesh
from tavf_mapkit.mesh.tiles import map_origin
from tavf_mapkit.world.objfile import obj_text
from tavf_mapkit.world.tiles import BodyPart, split_faces, tile_of

FORMAT = "tavf-mapkit collision world"
FORMAT_VERSION = 1
GROUPS = ("road", "roadside", "curb", "object", "signal", "building")
SOLID_GROUPS = ("curb", "object", "signal", "building")


def collision_parts(surface: LabelledMesh, solids, origin: np.ndarray, tile: float) -> list[BodyPart]:
    """Every body of the world, ordered by tile and group."""
    parts = []
    if len(surface.faces):
        drivable = np.isin(surface.kind, [KIND_CODE[k] for k in DRIVABLE_KINDS])
        centroids = surface.vertices[surface.faces].mean(axis=1)
        tiles = tile_of(centroids[:, :2], origin[:2], tile)
        for group, mask in (("road", drivable), ("roadside", ~drivable)):
            parts.extend(split_faces(surface.select(mask), tiles[mask], group))
    for group in SOLID_GROUPS:
        members = [solid for solid in solids if solid.kind == group]
        if not members:
            continue
        mesh = LabelledMesh.concatenate([solid.mesh for solid in members])
        centres = np.array([0.5 * (s.mesh.vertices.min(axis=0) + s.mesh.vertices.max(axis=0))[:2] for s in members])
        per_face = np.repeat(tile_of(centres, origin[:2], tile), [len(s.mesh.faces) for s in members], axis=0)
        parts.extend(split_faces(mesh, per_face, group))
    rank = {group: k for k, group in enumerate(GROUPS)}
    return sorted(parts, key=lambda p: (p.index[1], p.index[0], rank[p.group], p.name))


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
    """
    from tavf_mapkit.mesh.solids import scene_solid_parts

    if not (eps > 0 and np.isfinite(eps)):
        raise ValueError("eps must be a positive number of metres")
    if not (tile > 0 and np.isfinite(tile)):
        raise ValueError("tile must be a positive number of metres")
    if surface is None:
        from tavf_mapkit.mesh import road_surface

        surface = road_surface(odr, eps=eps)
    if scene is None:
        scene = scene_solid_parts(odr, surface, osm_path, eps)
    if origin is None:
        origin = map_origin([surface, scene.mesh()])
    origin = np.asarray(origin, dtype=np.float64).reshape(3) + 0.0
    if not np.all(np.isfinite(origin)):
        raise ValueError("origin must be three finite numbers")
    parts = collision_parts(surface, scene.solids, origin, tile)

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=".collision-", dir=out_dir))
    try:
        (staging / "tiles").mkdir()
        bodies, tiles = [], {}
        for part in parts:
            relative = f"tiles/{part.name}.obj"
            local = part.mesh.vertices - origin
            data = obj_text(part.name, local, part.mesh.faces,
                            f"{FORMAT}: {part.group} of {part.tile}, metres, pybullet = OpenDRIVE local - origin"
                            ).encode("ascii")
            (staging / relative).write_bytes(data)
            bodies.append({
                "name": part.name, "tile": part.tile, "group": part.group, "file": relative,
                "sha256": hashlib.sha256(data).hexdigest(),
                "vertices": len(part.mesh.vertices), "triangles": len(part.mesh.faces),
                "kinds": _kind_counts(part.mesh),
                "bounds": [np.round(local.min(axis=0), 4).tolist(), np.round(local.max(axis=0), 4).tolist()],
            })
            entry = tiles.setdefault(part.tile, {
                "name": part.tile, "index": list(part.index),
                "bounds": [part.index[0] * tile, part.index[1] * tile, (part.index[0] + 1) * tile,
                           (part.index[1] + 1) * tile],
                "bodies": []})
            entry["bodies"].append(part.name)
        geo = odr.header
        world = {
            "format": FORMAT, "version": FORMAT_VERSION,
            "origin": origin.tolist(),
            "frame": "x east, y north, z up, metres (OpenDRIVE local axes); pybullet = OpenDRIVE local - origin",
            "eps": eps, "tile_size": tile,
            "georeference": {"proj": geo.geo_reference,
                             "offset": None if geo.offset is None else {
                                 "x": geo.offset.x, "y": geo.offset.y, "z": geo.offset.z, "hdg": geo.offset.hdg}},
            "groups": {"road": list(DRIVABLE_KINDS), "roadside": "other road-surface kinds",
                       "curb": "solids", "object": "solids", "signal": "solids", "building": "solids"},
            "tiles": list(tiles.values()),
            "bodies": bodies,
            "solids": {**scene.counts(), "skipped": list(scene.skipped)},
            "totals": {"tiles": len(tiles), "bodies": len(bodies),
                       "vertices": int(sum(b["vertices"] for b in bodies)),
                       "triangles": int(sum(b["triangles"] for b in bodies))},
        }
        (staging / "world.json").write_text(json.dumps(world, indent=1) + "\n", encoding="utf-8")
        _swap_in(staging, out_dir / "collision")
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return world


def _swap_in(staging: Path, target: Path) -> None:
    """Put the finished folder in place; an older one is moved aside first and removed afterwards."""
    old = None
    if target.exists():
        old = target.with_name(f".{target.name}-old-{os.getpid()}")
        os.replace(target, old)
    os.replace(staging, target)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
