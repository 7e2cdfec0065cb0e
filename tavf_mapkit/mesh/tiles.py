"""Map origin and THE tile grid: float32-safe coordinates and files of a manageable size for large maps.

The origin is the centre of the map's plan-view bounds, rounded to whole metres (z: 0). Tiles are squares of
``size`` metres on a grid centred on the origin (tile (0, 0) is the square around it, so a map smaller
than a tile is one file). The mesh files, the labelled tiles and the collision world all use this one grid,
with the same squares and names: a face belongs to the tile of its centroid (so a tile holds whole triangles
and may reach a little over its square), a solid in the collision world to the tile of its bounding-box centre.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tavf_mapkit.mesh.labelled import LabelledMesh


@dataclass(frozen=True)
class Grid:
    origin: tuple[float, float, float]  # OpenDRIVE local coordinates of the export's (0, 0, 0)
    size: float

    def tile_of_points(self, xy: np.ndarray) -> np.ndarray:
        """(n, 2) int tile index (i, j) of plan-view points in OpenDRIVE local coordinates."""
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        return np.floor((xy - np.array(self.origin[:2])) / self.size + 0.5).astype(np.int64)

    def tile_of(self, mesh: LabelledMesh) -> np.ndarray:
        """(M, 2) int tile index (i, j) of each face (the tile of its centroid)."""
        if not len(mesh.faces):
            return np.zeros((0, 2), dtype=np.int64)
        return self.tile_of_points(face_centroids(mesh)[:, :2])

    def tile_bounds(self, index) -> list[float]:
        """[west, south, east, north] of a tile in OpenDRIVE local coordinates."""
        i, j = index
        x0, y0 = self.origin[0] + (i - 0.5) * self.size, self.origin[1] + (j - 0.5) * self.size
        return [x0, y0, x0 + self.size, y0 + self.size]

    def relative_bounds(self, index) -> list[float]:
        """[west, south, east, north] of a tile relative to the origin (the collision world's pybullet frame)."""
        i, j = index
        return [(i - 0.5) * self.size, (j - 0.5) * self.size, (i + 0.5) * self.size, (j + 0.5) * self.size]


def faces_by_tile(face_tiles: np.ndarray) -> dict[tuple[int, int], np.ndarray]:
    """tile index -> ascending face indices of the faces in that tile."""
    if not len(face_tiles):
        return {}
    order = np.lexsort((face_tiles[:, 1], face_tiles[:, 0]))  # stable: faces keep their order in a tile
    ordered = face_tiles[order]
    starts = np.flatnonzero(np.r_[True, np.any(ordered[1:] != ordered[:-1], axis=1)])
    ends = np.r_[starts[1:], len(order)]
    return {(int(ordered[a, 0]), int(ordered[a, 1])): order[a:b] for a, b in zip(starts.tolist(), ends.tolist())}


def face_centroids(mesh: LabelledMesh) -> np.ndarray:
    """(M, 3) centroid of every face (the one rule every tiling uses, so all agree to the bit)."""
    return mesh.vertices[mesh.faces].mean(axis=1)


def solid_centres(meshes: list[LabelledMesh]) -> np.ndarray:
    """(n, 2) plan-view centre of each solid's bounding box (where a solid sits whole in the collision world)."""
    if not meshes:
        return np.zeros((0, 2))
    return np.array([0.5 * (m.vertices.min(axis=0) + m.vertices.max(axis=0))[:2] for m in meshes])


def origin_of_bounds(low, high) -> tuple[float, float, float]:
    """The origin rule on plan-view bounds (low and high x, y of every vertex); (0, 0, 0) without any."""
    if low is None or high is None:
        return (0.0, 0.0, 0.0)
    centre = np.round(0.5 * (np.asarray(low, dtype=float) + np.asarray(high, dtype=float)))
    return (float(centre[0]) + 0.0, float(centre[1]) + 0.0, 0.0)  # + 0.0: no -0.0 in mesh.json


def map_origin(meshes: list[LabelledMesh]) -> tuple[float, float, float]:
    points = [m.vertices for m in meshes if len(m.vertices)]
    if not points:
        return (0.0, 0.0, 0.0)
    allp = np.concatenate(points)
    return origin_of_bounds(allp[:, :2].min(axis=0), allp[:, :2].max(axis=0))


def tile_name(index) -> str:
    i, j = (int(v) for v in index)
    return f"tile_{i:+d}_{j:+d}"
