"""THE tile grid of a build: which square of the map a point or a box belongs to, and what that square is called.

Tiles are squares of ``size`` metres on a grid centred on the build's origin (OpenDRIVE local coordinates):
tile (0, 0) is the square around the origin, so a map smaller than a tile is one file. Tile (i, j) is named
``tile_{i:+d}_{j:+d}`` ("tile_-1_+2"). The mesh files and labelled tiles (mesh/), the collision world (world/),
the report and the twin all use this one grid, with the same squares and names:

- a point belongs to the tile whose square holds it (a point on a west or south edge to that tile);
- a box (a solid) belongs to the tile of its centre, so it stays whole in one tile;
- a mesh face belongs to the tile of its centroid (``mesh.tiles``), so a tile holds whole triangles and may reach
  a little over its square.

The mesher spills its pieces on a grid of the same kind before the origin is known (``TileGrid.spill``: squares
with a corner at local (0, 0)); every build output uses the final grid.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

_NAME = re.compile(r"tile_([+-]\d+)_([+-]\d+)")


@dataclass(frozen=True)
class TileGrid:
    origin: tuple[float, float, float]  # OpenDRIVE local coordinates of the build's (0, 0, 0): tile (0, 0)'s centre
    size: float                          # edge of a tile, metres

    def __post_init__(self) -> None:
        if not (self.size > 0 and np.isfinite(self.size)):
            raise ValueError("tile size must be a positive number of metres")

    @classmethod
    def spill(cls, size: float) -> TileGrid:
        """The grid of the same squares' size with a corner at local (0, 0): where the mesher puts pieces while
        the origin (the middle of everything it makes) is not known yet."""
        return cls((0.5 * size, 0.5 * size, 0.0), float(size))

    @classmethod
    def of(cls, document: dict) -> TileGrid:
        """The grid a build file records: mesh/mesh.json (origin {x, y, z}), collision/world.json and
        mesh/labelled/index.json (origin [x, y, z]), each with ``tile_size``."""
        origin = document["origin"]
        if isinstance(origin, dict):
            origin = [origin[k] for k in "xyz"]
        return cls(tuple(float(v) + 0.0 for v in origin), float(document["tile_size"]))

    def tile_of_points(self, xy) -> np.ndarray:
        """(n, 2) int tile index (i, j) of plan-view points in OpenDRIVE local coordinates."""
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        return np.floor((xy - np.array(self.origin[:2])) / self.size + 0.5).astype(np.int64)

    def tile_of_point(self, x: float, y: float) -> tuple[int, int]:
        i, j = self.tile_of_points([x, y])[0]
        return int(i), int(j)

    def tile_of_boxes(self, low, high) -> np.ndarray:
        """(n, 2) tile index of boxes given by their (n, 2+) low and high corners: the tile of each box's centre."""
        low, high = np.asarray(low, dtype=float), np.asarray(high, dtype=float)
        return self.tile_of_points(0.5 * (low[..., :2] + high[..., :2]))

    def tiles_touching(self, box, margin: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """First and last tile index (inclusive) of the tiles whose points may lie within ``margin`` of ``box``
        (west, south, east, north): every point of the grown box belongs to one of them."""
        box = np.asarray(box, dtype=float)
        return self.tile_of_points(box[:2] - margin)[0], self.tile_of_points(box[2:] + margin)[0]

    def tile_bounds(self, index) -> list[float]:
        """[west, south, east, north] of a tile in OpenDRIVE local coordinates."""
        i, j = index
        x0, y0 = self.origin[0] + (i - 0.5) * self.size, self.origin[1] + (j - 0.5) * self.size
        return [x0, y0, x0 + self.size, y0 + self.size]

    def relative_bounds(self, index) -> list[float]:
        """[west, south, east, north] of a tile relative to the origin (the collision world's pybullet frame)."""
        i, j = index
        return [(i - 0.5) * self.size, (j - 0.5) * self.size, (i + 0.5) * self.size, (j + 0.5) * self.size]

    def name_of_point(self, x: float, y: float) -> str:
        return tile_name(self.tile_of_point(x, y))


def tile_name(index) -> str:
    i, j = (int(v) for v in index)
    return f"tile_{i:+d}_{j:+d}"


def tile_index(name: str) -> tuple[int, int]:
    """The index of a tile name ("tile_-1_+2" -> (-1, 2)); ValueError for anything else."""
    match = _NAME.fullmatch(name)
    if match is None:
        raise ValueError(f"not a tile name: {name!r}")
    return int(match.group(1)), int(match.group(2))


def group_by_tile(tiles: np.ndarray) -> dict[tuple[int, int], np.ndarray]:
    """tile index -> ascending row numbers of the (n, 2) tile indices that fall in that tile."""
    if not len(tiles):
        return {}
    order = np.lexsort((tiles[:, 1], tiles[:, 0]))  # stable: rows keep their order in a tile
    ordered = tiles[order]
    starts = np.flatnonzero(np.r_[True, np.any(ordered[1:] != ordered[:-1], axis=1)])
    ends = np.r_[starts[1:], len(order)]
    return {(int(ordered[a, 0]), int(ordered[a, 1])): order[a:b] for a, b in zip(starts.tolist(), ends.tolist())}


def origin_of_bounds(low, high) -> tuple[float, float, float]:
    """The origin rule on plan-view bounds (low and high x, y of everything a build meshes): their middle,
    rounded to whole metres, z = 0; (0, 0, 0) without any."""
    if low is None or high is None:
        return (0.0, 0.0, 0.0)
    centre = np.round(0.5 * (np.asarray(low, dtype=float) + np.asarray(high, dtype=float)))
    return (float(centre[0]) + 0.0, float(centre[1]) + 0.0, 0.0)  # + 0.0: no -0.0 in mesh.json
