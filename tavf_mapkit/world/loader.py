"""Load a build's collision world into a pybullet client: ``tavf_mapkit.world.load(build_dir, client_id)``."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

from tavf_mapkit.errors import InputError
from tavf_mapkit.world.bodies import Body, WorldBodies
from tavf_mapkit.world.build import FORMAT, FORMAT_VERSION


def world_file(path: str | Path) -> Path:
    """collision/world.json of a build folder (also accepts the collision folder or the file itself)."""
    path = Path(path)
    for candidate in (path / "collision" / "world.json", path / "world.json", path):
        if candidate.is_file():
            return candidate
    raise InputError("no collision world here (expected collision/world.json; run `mapkit build`)",
                     file=str(path))


def read_world(path: str | Path) -> dict:
    file = world_file(path)
    try:
        world = json.loads(file.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise InputError(f"unreadable collision world: {error}", file=str(file)) from None
    if not isinstance(world, dict) or world.get("format") != FORMAT:
        raise InputError(f"not a collision world (format is not {FORMAT!r})", file=str(file))
    if world.get("version") != FORMAT_VERSION:
        raise InputError(f"collision world version {world.get('version')!r} is not supported "
                         f"(this mapkit reads version {FORMAT_VERSION}); rebuild it", file=str(file))
    return world


def collision_shape(entry: dict, folder: Path, physics_client_id: int, verify: bool = True) -> int:
    """The pybullet collision shape of one world.json body, its OBJ checked against the recorded sha256."""
    import pybullet

    path = folder / entry["file"]
    try:
        data = path.read_bytes()
    except OSError as error:
        raise InputError(f"collision body {entry['name']}: {error.strerror}", file=str(path)) from None
    if verify and hashlib.sha256(data).hexdigest() != entry.get("sha256"):
        raise InputError(f"collision body {entry['name']} does not match world.json (changed or truncated)",
                         file=str(path))
    shape = pybullet.createCollisionShape(pybullet.GEOM_MESH, fileName=str(path),
                                          flags=pybullet.GEOM_FORCE_CONCAVE_TRIMESH,
                                          physicsClientId=physics_client_id)
    if shape < 0:
        raise InputError(f"pybullet could not load collision body {entry['name']}", file=str(path))
    return shape


def load(build_dir: str | Path, physics_client_id: int = 0, verify: bool = True) -> WorldBodies:
    """Create one static concave-mesh body per entry of world.json in the given pybullet client.

    Bodies are created in the file's order, so the same build gives the same body ids in a fresh client.
    With ``verify`` every OBJ is checked against the sha256 that world.json records.
    """
    import pybullet

    file = world_file(build_dir)
    world = read_world(file)
    folder = file.parent
    bodies = []
    for entry in world.get("bodies", []):
        shape = collision_shape(entry, folder, physics_client_id, verify)
        body_id = pybullet.createMultiBody(baseMass=0, baseCollisionShapeIndex=shape,
                                           physicsClientId=physics_client_id)
        bodies.append(Body(entry["name"], entry["tile"], entry["group"], body_id, entry["file"]))
    return WorldBodies(np.asarray(world["origin"], dtype=np.float64), tuple(bodies), physics_client_id,
                       float(world.get("tile_size", 0.0)), float(world.get("eps", 0.0)))
