"""Ray casts against the static collision world with Intel Embree (``embreex``, through trimesh).

pybullet's ``rayTestBatch`` costs ~1.4 us per ray in marshalling alone, ~70 ms for a 32 x 1024 lidar scan;
Embree casts the same scan against the same triangles (the world's OBJ tiles) in ~3 ms. Bodies that are
not part of the static world (SUMO traffic and the like) are still cast in pybullet, but only the rays
whose line passes their bounding box.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pybullet as pb


def available() -> bool:
    try:
        import embreex  # noqa: F401
    except ImportError:
        return False
    return True


class EmbreeWorld:
    """The collision world's triangles in pybullet coordinates, with the body id of every triangle: the whole
    world (``EmbreeWorld(collision_dir, bodies)``, ``bodies`` as ``tavf_mapkit.world.load`` made them), or the
    tiles a ``TileStream`` has loaded now (``EmbreeWorld.following(stream)``: rebuilt when they change)."""

    def __init__(self, collision_dir: Path | None = None, bodies=None):
        self.stream = None
        self._generation = None
        self._meshes: dict[int, object] = {}  # world id -> trimesh of a loaded body (streamed)
        if collision_dir is None:
            return
        world = json.loads((Path(collision_dir) / "world.json").read_text(encoding="utf-8"))
        by_name = {body.name: body.body_id for body in bodies.bodies}
        self._set([(by_name[entry["name"]], _mesh(Path(collision_dir) / entry["file"]))
                   for entry in world["bodies"]])

    @classmethod
    def following(cls, stream) -> EmbreeWorld:
        scene = cls()
        scene.stream = stream
        scene._refresh()
        return scene

    def _set(self, bodies: list) -> None:
        """Cast against these (pybullet id, trimesh) bodies."""
        import trimesh
        from trimesh.ray.ray_pyembree import RayMeshIntersector

        meshes = [mesh for _, mesh in bodies if len(mesh.faces)]
        owners = [np.full(len(mesh.faces), body, dtype=np.int64) for body, mesh in bodies if len(mesh.faces)]
        self.mesh = trimesh.util.concatenate(meshes) if meshes else None
        self.face_body = np.concatenate(owners) if owners else np.zeros(0, dtype=np.int64)
        self.intersector = RayMeshIntersector(self.mesh) if meshes else None
        self.static_ids = frozenset(body for body, _ in bodies)

    def _refresh(self) -> None:
        """Follow the stream: the bodies it has loaded now, each OBJ read once while its tile stays."""
        stream = self.stream
        if stream is None or stream.generation == self._generation:
            return
        loaded = stream.loaded_ids()  # pybullet id -> world id
        wanted = set(loaded.values())
        self._meshes = {k: mesh for k, mesh in self._meshes.items() if k in wanted}
        for k in sorted(wanted - set(self._meshes)):
            self._meshes[k] = _mesh(stream.folder / stream.entries[k]["file"])
        self._set([(body, self._meshes[k]) for body, k in sorted(loaded.items(), key=lambda item: item[1])])
        self._generation = stream.generation

    def first_hits(self, origin: np.ndarray, directions: np.ndarray, max_range: float):
        """(range m, inf without a hit; pybullet body id or -1) of rays from one origin (pybullet frame)."""
        self._refresh()
        if self.intersector is None:
            return np.full(len(directions), np.inf), np.full(len(directions), -1, dtype=np.int64)
        origins = np.broadcast_to(origin, directions.shape)
        locations, ray, face = self.intersector.intersects_location(origins, directions, multiple_hits=False)
        ranges = np.full(len(directions), np.inf)
        body = np.full(len(directions), -1, dtype=np.int64)
        distance = np.linalg.norm(locations - origin, axis=1)
        keep = distance <= max_range
        ranges[ray[keep]] = distance[keep]
        body[ray[keep]] = self.face_body[face[keep]]
        return ranges, body


def _mesh(path: Path):
    import trimesh

    return trimesh.load(path, force="mesh", process=False)


def dynamic_hits(client_id: int, ignore_ids, origin: np.ndarray, directions: np.ndarray, max_range: float,
                 ranges: np.ndarray, body: np.ndarray) -> None:
    """Lower ``ranges`` where a pybullet body outside ``ignore_ids`` (the static world, the twin's own cars,
    which rays never hit) is hit first (in place)."""
    for index in range(pb.getNumBodies(physicsClientId=client_id)):
        other = pb.getBodyUniqueId(index, physicsClientId=client_id)
        if other in ignore_ids:
            continue
        low, high = (np.asarray(v) for v in pb.getAABB(other, physicsClientId=client_id))
        if np.all(low < -999.0) or np.linalg.norm(np.clip(origin, low, high) - origin) > max_range:
            continue
        with np.errstate(divide="ignore", invalid="ignore"):
            t1, t2 = (low - origin) / directions, (high - origin) / directions
        near = np.nanmax(np.minimum(t1, t2), axis=1)
        far = np.nanmin(np.maximum(t1, t2), axis=1)
        candidates = np.flatnonzero((far >= np.maximum(near, 0.0)) & (near < np.minimum(ranges, max_range)))
        if not len(candidates):
            continue
        ends = origin + directions[candidates] * max_range
        results = pb.rayTestBatch([origin.tolist()] * len(candidates), ends.tolist(), physicsClientId=client_id)
        for k, hit in zip(candidates, results):
            distance = hit[2] * max_range
            if hit[0] == other and distance < ranges[k]:
                ranges[k], body[k] = distance, other
