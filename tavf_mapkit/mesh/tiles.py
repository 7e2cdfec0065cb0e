"""Map origin and tiles: float32-safe coordinates and files of a manageable size for large maps.

The origin is the centre of the map's plan-view bounds, rounded to whole metres (z: 0). Tiles are squares of
``size`` metres on a grid centred on the origin (tile (0, 0) is the square around it, so a map smaller
than a tile is one file); a face belongs to the tile of its centroid, so a tile file
holds whole triangles and may reach a little over its square.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tavf_mapkit.mesh.labelled import LabelledMesh


@dataclass(frozen=True)
class Grid:
    origin: tuple[float, float, float]  # OpenDRIVE local coordinates of the export's (0, 0, 0)
    size: float

    def tile_of(self, mesh: LabelledMesh) -> np.ndarray:
        """(M, 2) int tile index (i, j) of each face."""
        if not len(mesh.faces):
            return np.zeros((0, 2), dtype=np.int64)
        centre = mesh.vertices[mesh.faces].mean(axis=1)[:, :2] - np.array(self.origin[:2])
        return np.floor(centre / self.size + 0.5).astype(np.int64)

    def tile_bounds(self, index) -> list[float]:
        """[west, south, east, north] of a tile in OpenDRIVE local coordinates."""
        i, j = index
        x0, y0 = self.origin[0] + (i - 0.5) * self.size, self.origin[1] + (j - 0.5) * self.size
        return [x0, y0, x0 + self.size, y0 + self.size]


def map_origin(meshes: list[LabelledMesh]) -> tuple[float, float, float]:
    points = [m.vertices for m in meshes if len(m.vertices)]
    if not points:
        return (0.0, 0.0, 0.0)
    allp = np.concatenate(points)
    low, high = allp[:, :2].min(axis=0), allp[:, :2].max(axis=0)
    centre = np.round(0.5 * (low + high))
    return (float(centre[0]) + 0.0, float(centre[1]) + 0.0, 0.0)  # + 0.0: no -0.0 in mesh.json


def tile_name(index) -> str:
    i, j = (int(v) for v in index)
    return f"tile_{i:+d}_{j:+d}"
