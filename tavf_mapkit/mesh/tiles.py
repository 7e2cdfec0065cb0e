"""Where meshes fall on the tile grid (``tavf_mapkit.tilegrid``) and the map origin of a set of meshes.

A face belongs to the tile of its centroid (so a tile holds whole triangles and may reach a little over its
square); a solid of the collision world to the tile of its bounding-box centre (so it stays whole).
"""

from __future__ import annotations

import numpy as np

from tavf_mapkit.mesh.labelled import LabelledMesh
from tavf_mapkit.tilegrid import TileGrid, origin_of_bounds


def face_tiles(grid: TileGrid, mesh: LabelledMesh) -> np.ndarray:
    """(M, 2) int tile index (i, j) of each face (the tile of its centroid)."""
    if not len(mesh.faces):
        return np.zeros((0, 2), dtype=np.int64)
    return grid.tile_of_points(face_centroids(mesh)[:, :2])


def face_centroids(mesh: LabelledMesh) -> np.ndarray:
    """(M, 3) centroid of every face (the one rule every tiling uses, so all agree to the bit)."""
    return mesh.vertices[mesh.faces].mean(axis=1)


def solid_tiles(grid: TileGrid, meshes: list[LabelledMesh]) -> np.ndarray:
    """(n, 2) int tile index of each solid: the tile of its bounding box's centre."""
    if not meshes:
        return np.zeros((0, 2), dtype=np.int64)
    return grid.tile_of_boxes(np.array([m.vertices.min(axis=0) for m in meshes]),
                              np.array([m.vertices.max(axis=0) for m in meshes]))


def map_origin(meshes: list[LabelledMesh]) -> tuple[float, float, float]:
    """The origin rule (``tilegrid.origin_of_bounds``) on the plan-view bounds of every vertex of the meshes."""
    points = [m.vertices for m in meshes if len(m.vertices)]
    if not points:
        return (0.0, 0.0, 0.0)
    allp = np.concatenate(points)
    return origin_of_bounds(allp[:, :2].min(axis=0), allp[:, :2].max(axis=0))
