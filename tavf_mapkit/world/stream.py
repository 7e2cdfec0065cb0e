"""The collision world streamed into a pybullet client tile by tile around moving points (the twin's cars),
as CARLA's large maps do: ``TileStream(build_dir, client_id, radius).cover(points)``.

``load`` puts every body of a build into pybullet: on a region that is hundreds of MB and seconds of start.
A stream loads only the tiles whose bodies come within ``radius`` of a covered point and drops tiles once all
points are more than ``radius + hysteresis`` away, so its memory grows with the radius, not with the map.

What a query sees is what the whole world gives: a ray or contact query that reaches at most ``radius`` from
a covered point can only meet bodies whose bounding boxes come that close, and those tiles are loaded (a tile
is judged by the boxes of its bodies, which may reach over its square: whole solids, faces by centroid).
Bodies keep one id per body whatever pybullet numbers them: the world id, the body's index in world.json,
which is the pybullet id ``load`` gives it in a fresh client (``world_ids`` translates).
"""

from __future__ import annotations

import numpy as np

from tavf_mapkit.world.bodies import Body, WorldBodies
from tavf_mapkit.world.loader import collision_shape, read_world, world_file


class TileStream:
    """The tiles of a build's collision world near the covered points, in one pybullet client."""

    def __init__(self, build_dir, physics_client_id: int, radius: float, hysteresis: float | None = None,
                 verify: bool = True):
        file = world_file(build_dir)
        world = read_world(file)
        self.folder = file.parent
        self.client_id = physics_client_id
        self.verify = verify
        entries = world.get("bodies", [])
        self.entries = entries
        # the catalogue: every body with its world id (what ``load`` would make its pybullet id); its
        # ``cast_down`` would see only the loaded tiles and answer pybullet ids: cover first, translate after
        self.catalogue = WorldBodies(
            np.asarray(world["origin"], dtype=np.float64),
            tuple(Body(e["name"], e["tile"], e["group"], k, e["file"]) for k, e in enumerate(entries)),
            physics_client_id, float(world.get("tile_size", 0.0)), float(world.get("eps", 0.0)))
        self.tile_size = self.catalogue.tile_size if self.catalogue.tile_size > 0 else 100.0
        self._origin_xy = self.catalogue.origin[:2].copy()
        self.radius = float(radius)
        self.hysteresis = self.tile_size if hysteresis is None else float(hysteresis)
        if not (self.radius >= 0 and np.isfinite(self.radius) and self.hysteresis >= 0):
            raise ValueError("radius and hysteresis must be finite metres >= 0")
        self._tiles_of_bodies(entries)
        self.loaded: dict[int, list[int]] = {}   # tile number -> pybullet ids of its bodies (world.json order)
        # pybullet id + 1 -> world id; [0] answers -1 (no hit), bodies not of the world len(bodies) + their id
        self._table = np.full(1, -1, dtype=np.int64)
        # world id -> collision shape. pybullet frees a shape only with resetSimulation (removeCollisionShape
        # refuses a shape a body ever used: bullet3 #2086, #4326), so a dropped tile's shapes are kept and
        # reused when it comes back: memory grows with the tiles visited, never past the whole world
        self._shapes: dict[int, int] = {}
        self._world: dict[int, int] = {}  # pybullet id -> world id of the bodies loaded now
        self._cells: tuple | None = None  # the grid squares covered now
        self._last: np.ndarray | None = None  # the points' squares at the last call, in their order
        self.generation = 0  # +1 whenever the loaded set changes (consumers with caches rebuild then)
        self.loads = self.drops = 0

    def _tiles_of_bodies(self, entries: list) -> None:
        """Per tile (in world.json's order of first appearance): its bodies and the box around their bounds."""
        names = [entry["tile"] for entry in entries]
        number = {name: t for t, name in enumerate(dict.fromkeys(names))}
        tile = np.fromiter((number[name] for name in names), dtype=np.int64, count=len(names))
        by_tile = np.argsort(tile, kind="stable")  # each tile's bodies in world.json's order
        cuts = np.cumsum(np.bincount(tile, minlength=len(number)))[:-1]
        self.tile_bodies = [part.tolist() for part in np.split(by_tile, cuts)] if len(number) else []
        self.tile_names = list(number)
        # bounds [[x, y, z] low, [x, y, z] high] in one array (a region has tens of thousands of bodies)
        bounds = np.array([entry["bounds"] for entry in entries], dtype=np.float64).reshape(-1, 2, 3)
        low = np.full((len(number), 2), np.inf)
        high = np.full((len(number), 2), -np.inf)
        np.minimum.at(low, tile, bounds[:, 0, :2])
        np.maximum.at(high, tile, bounds[:, 1, :2])
        self.tile_low, self.tile_high = low, high  # pybullet frame (OpenDRIVE local - origin)

    # ------------------------------------------------------------------ covering
    def cover(self, points_local) -> None:
        """Make the world complete within ``radius`` of every (x, y) point (OpenDRIVE local coordinates), and
        drop tiles beyond ``radius + hysteresis`` of all of them. Cheap while no point changes its grid square:
        each square is covered whole, so nothing needs doing until a point leaves it."""
        xy = np.asarray(points_local, dtype=np.float64).reshape(-1, 2)
        cells = np.floor((xy - self._origin_xy) * (1.0 / self.tile_size) + 0.5)
        last = self._last
        if last is not None and last.shape == cells.shape and (last == cells).all():
            return  # the step's usual case: every point in the square it was in
        self._last = cells
        key = tuple(map(tuple, np.unique(cells.astype(np.int64), axis=0).tolist()))
        if key == self._cells:
            return
        distance = self._distance_to_cells(np.asarray(key, dtype=np.float64))
        wanted = np.flatnonzero(distance <= self.radius)
        keep = distance <= self.radius + self.hysteresis
        changed = False
        for t in [t for t in self.loaded if not keep[t]]:
            self._drop(t)
            changed = True
        for t in wanted.tolist():
            if t not in self.loaded:
                self._load(t)
                changed = True
        self._cells = key
        self.generation += changed

    def _distance_to_cells(self, cells: np.ndarray) -> np.ndarray:
        """Per tile: the least plan distance between its bodies' box and any of the grid squares ``cells``."""
        best = np.full(len(self.tile_low), np.inf)
        for i, j in cells:
            x0, x1, y0, y1 = (i - 0.5) * self.tile_size, (i + 0.5) * self.tile_size, \
                (j - 0.5) * self.tile_size, (j + 0.5) * self.tile_size
            dx = np.maximum.reduce([self.tile_low[:, 0] - x1, x0 - self.tile_high[:, 0], np.zeros(len(best))])
            dy = np.maximum.reduce([self.tile_low[:, 1] - y1, y0 - self.tile_high[:, 1], np.zeros(len(best))])
            np.minimum(best, np.hypot(dx, dy), out=best)
        return best

    def _load(self, tile: int) -> None:
        ids = []
        try:
            for k in self.tile_bodies[tile]:
                ids.append(self._create(k))
        except BaseException:
            for body in ids:
                self._remove(body)
            raise
        self.loaded[tile] = ids
        self.loads += 1

    def _create(self, k: int) -> int:
        import pybullet

        shape = self._shapes.get(k)
        if shape is None:
            shape = self._shapes[k] = self._shape(k)
        body = pybullet.createMultiBody(baseMass=0, baseCollisionShapeIndex=shape,
                                        physicsClientId=self.client_id)
        if body + 1 >= len(self._table):
            self._grow(body)
        self._table[body + 1] = k
        self._world[body] = k
        return body

    def _shape(self, k: int) -> int:
        """The collision shape of body ``k`` (the loader's, checked against world.json's sha256)."""
        return collision_shape(self.entries[k], self.folder, self.client_id, self.verify)

    def _remove(self, body: int) -> None:
        import pybullet

        pybullet.removeBody(body, physicsClientId=self.client_id)
        self._table[body + 1] = len(self.entries) + body  # pybullet may give the id to another body
        del self._world[body]

    def _drop(self, tile: int) -> None:
        for body in reversed(self.loaded.pop(tile)):
            self._remove(body)
        self.drops += 1

    # ------------------------------------------------------------------ ids
    def world_ids(self, pybullet_ids) -> np.ndarray:
        """World ids of pybullet ids: a loaded world body's index in world.json; -1 stays -1 (no hit); any
        other pybullet body (cars, traffic) ``len(bodies) + its pybullet id``, never a world body's id."""
        ids = np.asarray(pybullet_ids, dtype=np.int64)
        if ids.size and int(ids.max()) + 1 >= len(self._table):
            self._grow(int(ids.max()))
        return self._table[ids + 1]

    def world_id(self, pybullet_id: int) -> int:
        """``world_ids`` of one id (the contact loop's)."""
        if pybullet_id + 1 >= len(self._table):
            self._grow(pybullet_id)
        return int(self._table[pybullet_id + 1])

    def _grow(self, pybullet_id: int) -> None:
        """Make the table answer every pybullet id up to ``pybullet_id`` (and then some)."""
        old = len(self._table) - 1  # ids 0 .. old-1 answered now
        size = max(2 * old, pybullet_id + 1, 64)
        table = np.empty(size + 1, dtype=np.int64)
        table[:old + 1] = self._table
        table[old + 1:] = len(self.entries) + np.arange(old, size)
        self._table = table

    def loaded_ids(self) -> dict[int, int]:
        """pybullet id -> world id of every body loaded now."""
        return dict(self._world)

    def loaded_tiles(self) -> list[str]:
        return sorted(self.tile_names[t] for t in self.loaded)

    def close(self) -> None:
        """Drop every tile (the client stays)."""
        for tile in list(self.loaded):
            self._drop(tile)
        self._cells = self._last = None
        self.generation += 1
