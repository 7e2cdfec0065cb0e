"""Cut meshes into collision bodies on the build's tile grid (``tavf_mapkit.tilegrid``: squares centred on the
origin, the same squares and names as the mesh files and the labelled tiles).

A face belongs to the tile that holds its centroid; a solid stays whole in the tile of its bounding-box centre.
A body with more than MAX_BODY_VERTICES vertices is split into quarters until it fits, so every body also fits
pybullet's in-memory limit (131,072 vertices) should a caller load it from arrays instead of the OBJ file.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tavf_mapkit.mesh.labelled import LabelledMesh
from tavf_mapkit.tilegrid import tile_name

MAX_BODY_VERTICES = 100_000


@dataclass(frozen=True, eq=False)
class BodyPart:
    name: str       # "tile_-1_+2_road" (a split body adds "_q0".."_q3" per level)
    tile: str       # "tile_-1_+2"
    index: tuple[int, int]
    group: str      # road, roadside, curb, object, signal, building
    mesh: LabelledMesh


def tile_body_parts(mesh: LabelledMesh, index: tuple[int, int], group: str) -> list[BodyPart]:
    """The body of one tile and group (``mesh``: its faces only, every vertex used), or its quarters when it has
    too many vertices."""
    name = tile_name(index)
    return _fit(BodyPart(f"{name}_{group}", name, index, group, mesh))


def _fit(part: BodyPart) -> list[BodyPart]:
    """The part itself, or its quarters (recursively) when it has too many vertices."""
    mesh = part.mesh
    if len(mesh.vertices) <= MAX_BODY_VERTICES or len(mesh.faces) < 2:
        return [part]
    centroid = mesh.vertices[mesh.faces].mean(axis=1)
    mid = np.median(centroid[:, :2], axis=0)
    quarter = (centroid[:, 0] >= mid[0]).astype(int) + 2 * (centroid[:, 1] >= mid[1]).astype(int)
    if np.all(quarter == quarter[0]):  # all centroids on one spot: halve by face order instead
        quarter = (np.arange(len(quarter)) >= len(quarter) // 2).astype(int)
    out = []
    for q in range(4):
        mask = quarter == q
        if np.any(mask):
            out.extend(_fit(BodyPart(f"{part.name}_q{q}", part.tile, part.index, part.group, mesh.select(mask))))
    return out
