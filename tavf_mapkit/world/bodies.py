"""WorldBodies: what ``tavf_mapkit.world.load`` put into a pybullet client, and the coordinate conversion
between OpenDRIVE local coordinates and the pybullet world (pybullet = local - origin)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from tavf_mapkit.tilegrid import TileGrid

RAY_BATCH = 8192  # rays per rayTestBatch call (pybullet refuses batches above 16,384)


@dataclass(frozen=True)
class Body:
    name: str
    tile: str
    group: str      # road, roadside, curb, object, signal, building
    body_id: int
    file: str


@dataclass(frozen=True, eq=False)
class WorldBodies:
    origin: np.ndarray            # (3,) OpenDRIVE local coordinates of pybullet's (0, 0, 0)
    bodies: tuple[Body, ...]      # in world.json order
    client_id: int
    tile_size: float
    eps: float

    @cached_property
    def body_ids(self) -> tuple[int, ...]:
        return tuple(body.body_id for body in self.bodies)

    @cached_property
    def grid(self) -> TileGrid:
        """The build's tile grid (the mesh files' squares and names)."""
        return TileGrid(tuple(float(v) for v in self.origin), self.tile_size)

    def tile_at(self, x: float, y: float) -> str:
        """Name of the tile holding an OpenDRIVE local point (``by_tile`` has its bodies, if any)."""
        return self.grid.name_of_point(x, y)

    @cached_property
    def by_tile(self) -> dict[str, tuple[int, ...]]:
        out: dict[str, list[int]] = {}
        for body in self.bodies:
            out.setdefault(body.tile, []).append(body.body_id)
        return {tile: tuple(ids) for tile, ids in out.items()}

    @cached_property
    def by_group(self) -> dict[str, tuple[int, ...]]:
        out: dict[str, list[int]] = {}
        for body in self.bodies:
            out.setdefault(body.group, []).append(body.body_id)
        return {group: tuple(ids) for group, ids in out.items()}

    @cached_property
    def _group_of(self) -> dict[int, str]:
        return {body.body_id: body.group for body in self.bodies}

    def group_of(self, body_id: int) -> str | None:
        """road / roadside / curb / object / signal / building for a body of this world, else None."""
        return self._group_of.get(int(body_id))

    def to_pybullet(self, points) -> np.ndarray:
        """OpenDRIVE local (x, y[, z]) -> pybullet coordinates; (2,) / (n, 2) inputs keep their shape."""
        points = np.asarray(points, dtype=np.float64)
        return points - self.origin[: points.shape[-1]]

    def to_local(self, points) -> np.ndarray:
        """pybullet coordinates -> OpenDRIVE local coordinates."""
        points = np.asarray(points, dtype=np.float64)
        return points + self.origin[: points.shape[-1]]

    def cast_down(self, points_local, above: float = 1.0, below: float = 1.0):
        """Vertical rays through OpenDRIVE local points, from ``above`` metres over each to ``below`` under it.

        Returns (hit_z_local, body_id) per point: NaN and -1 where nothing was hit.
        """
        import pybullet

        points = self.to_pybullet(np.atleast_2d(points_local))
        start = points + np.array([0.0, 0.0, above])
        end = points - np.array([0.0, 0.0, below])
        z = np.full(len(points), np.nan)
        body = np.full(len(points), -1, dtype=np.int64)
        for i in range(0, len(points), RAY_BATCH):
            hits = pybullet.rayTestBatch(start[i:i + RAY_BATCH].tolist(), end[i:i + RAY_BATCH].tolist(),
                                         physicsClientId=self.client_id)
            for k, hit in enumerate(hits):
                if hit[0] >= 0:
                    z[i + k] = hit[3][2] + self.origin[2]
                    body[i + k] = hit[0]
        return z, body
