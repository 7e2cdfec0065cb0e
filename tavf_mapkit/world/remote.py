"""The collision world's tiles as Dask tasks (``mapkit build --workers N | --scheduler ADDR``): a task gets the
bytes of a few labelled tiles and sends back their body files (``world.build.tile_files``); the client writes
them in the single process's order, so collision/ comes out the same. No shared filesystem is needed."""

from __future__ import annotations

from pathlib import Path

from tavf_mapkit.cluster import batches_for
from tavf_mapkit.tilegrid import TileGrid

TILES_PER_TASK = 64


def remote_tile_files(fanout, grid: TileGrid, labelled: Path, tiles: list):
    """Body files of every (name, index) of ``tiles``, in order."""
    size = batches_for(len(tiles), fanout.workers, TILES_PER_TASK)
    groups = [tiles[start:start + size] for start in range(0, len(tiles), size)]
    arguments = (([(index, (Path(labelled) / f"{name}.npz").read_bytes()) for name, index in group],
                  grid.origin, grid.size) for group in groups)
    for files in fanout.map(_collision_task, arguments):
        yield from files


def _collision_task(tiles, origin, size):
    from tavf_mapkit.world.build import tile_files

    grid = TileGrid(tuple(origin), size)
    return [tile_files(grid, index, data) for index, data in tiles]
