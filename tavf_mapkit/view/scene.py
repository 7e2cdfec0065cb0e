"""What the 3D view loads: the build's mesh tiles (glTF, or OBJ for ``mapkit mesh --format obj`` folders) and
the collision world's bodies (OBJ per tile and group), with the frames they are written in.

Frames (docs/mesh.md, docs/collision-world.md): glTF tiles are +Y up, (X, Y, Z) = (x - ox, z - oz, -(y - oy))
of the OpenDRIVE local frame; collision OBJ files are local minus the world's origin, z up. The page puts
both, and the replay, into the glTF frame of the mesh's origin.
"""

from __future__ import annotations

import json
from pathlib import Path

from tavf_mapkit.errors import InputError


def scene_data(build: Path) -> dict:
    """{origin, mesh: {format, tiles: [url], materials}, collision: {origin, bodies: [{url, group}]}, bounds}.
    URLs are relative to the page (``build/mesh/...``, ``build/collision/...``); a stage that did not run
    leaves its part empty."""
    mesh = _read(build / "mesh" / "mesh.json")
    world = _read(build / "collision" / "world.json")
    origin = [0.0, 0.0, 0.0]
    if mesh and isinstance(mesh.get("origin"), dict):
        origin = [float(mesh["origin"].get(axis, 0.0)) for axis in ("x", "y", "z")]
    elif world and isinstance(world.get("origin"), list):
        origin = [float(v) for v in world["origin"]]
    tiles = [{"url": f"build/mesh/{tile['file']}", "bounds": tile.get("bounds")}
             for tile in (mesh or {}).get("tiles") or () if tile.get("file")]
    bodies = [{"url": f"build/collision/{body['file']}", "group": body.get("group")}
              for body in (world or {}).get("bodies") or () if body.get("file")]
    bounds = _bounds([tile["bounds"] for tile in tiles if tile.get("bounds")])
    return {
        "origin": origin,
        "mesh": {"format": (mesh or {}).get("format", "glb"), "tiles": tiles,
                 "materials": (mesh or {}).get("materials") or {}},
        "collision": {"origin": [float(v) for v in (world or {}).get("origin") or origin], "bodies": bodies},
        "bounds": bounds,
    }


def _read(path: Path) -> dict | None:
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except ValueError as error:
        raise InputError(f"unreadable JSON: {error}", file=str(path)) from None
    return data if isinstance(data, dict) else None


def _bounds(boxes: list) -> list | None:
    """[west, south, east, north] over the tiles' local bounds."""
    if not boxes:
        return None
    return [min(b[0] for b in boxes), min(b[1] for b in boxes), max(b[2] for b in boxes), max(b[3] for b in boxes)]
