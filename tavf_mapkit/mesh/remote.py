"""The tiled mesher's passes as Dask tasks (``mapkit build --workers N | --scheduler ADDR``): the same work as
``mesh.tiled`` does in one process, cut into tasks that need no shared filesystem, with the same files.

- pass 1, batches of units: a task meshes its roads and sends back its spilled chunks and tallies;
- pass 2, junction clusters' curbs: a task gets the spilled surface tiles around its clusters;
- pass 4, the final tiles: a task gets the spill tiles its squares take pieces from and sends back the tile file,
  the labelled tile and its paint on the preview (cropped masks, merged by ``PreviewCanvas.add_painted``).
Pass 3 (buildings) stays in the client, while the workers make the curbs: how far a building's ground search
reaches is known only while it runs.

Each task gets the client's loaded map and mesh units, pickled, as (sha256, bytes) from ``cluster.FileFanout``
(``share_map``), and unpickles them once per worker (``cluster.worker_object``). The client adds what the tasks
send back in the order the single process makes it, so the spill, the tallies and therefore every file are the
same; batches and groups are smaller than one process would take (several tasks per worker), which the mesher's
results do not depend on.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from tavf_mapkit.cluster import batches_for, worker_cached, worker_object
from tavf_mapkit.mesh.spill import MemoryStore
from tavf_mapkit.tilegrid import TileGrid

STORES = ("surface", "marks", "solids", "whole")
TASKS_PER_WORKER = 4   # tasks of a pass per worker at least: a slow task does not hold up the others for long
TILES_PER_TASK = 64    # squares of the final grid a task writes at most (its memory)


def _map_and_units(digest: str, data: bytes, name: str):
    """(map, mesh units) the client sent (``share_map``), unpickled once per worker."""
    return worker_object(digest, data, name)


def share_map(fanout, odr, units):
    """A ``cluster.FileFanout`` whose tasks get the client's loaded map and its mesh units, pickled (both made
    once, here: a worker unpickles them in about a tenth of the time it would take to read the OpenDRIVE and
    cut the units again, and while the client still plans the batches)."""
    mapped = fanout.with_object((odr, units), "the loaded map")
    mapped.everywhere(_preload_task)
    return mapped


def _preload_task(digest, data, name) -> None:
    _map_and_units(digest, data, name)


# what the tile stages' tasks import: the preview's paint, nearest-vertex searches, the mesher, tile files, the
# map's classes (to unpickle it), the collision world's tiles
TASK_MODULES = ("PIL.ImageChops", "PIL.ImageDraw", "scipy.spatial", "tavf_mapkit.mesh.export",
                "tavf_mapkit.mesh.marks", "tavf_mapkit.mesh.preview", "tavf_mapkit.mesh.solid_curbs",
                "tavf_mapkit.mesh.solid_junction_curbs", "tavf_mapkit.mesh.solid_objects",
                "tavf_mapkit.mesh.solid_signals", "tavf_mapkit.mesh.surface", "tavf_mapkit.mesh.tiled",
                "tavf_mapkit.opendrive.reader", "tavf_mapkit.world.build", "tavf_mapkit.world.remote")


def dask_setup(worker) -> None:
    """Run by every worker of a build's local cluster when it starts (Dask's worker preload,
    ``cluster.COMPUTING_TASKS_CONFIG``): the tasks' modules are imported then -- while the client still runs
    netconvert and the opendrive stage -- and not by each worker's first tasks (0.8 s of CPU per worker here)."""
    import importlib

    for name in TASK_MODULES:
        importlib.import_module(name)


def _replay(stores: dict, records: dict) -> None:
    """Chunks a task made, added to the client's stores in the order the task made them."""
    for name, chunks in records.items():
        store = stores[name]
        for key, data in chunks:
            store.add_blob(key, data)


def _records(stores: dict) -> dict:
    return {name: store.records for name, store in stores.items() if store.records}


# -- pass 1 ------------------------------------------------------------------------------------------------------

def mesh_batches(fanout, units, batch_work: float, eps: float, spill_grid: TileGrid, stores: dict, tally,
                 solids: bool, exports: bool, report, total_roads: int) -> int:
    """Pass 1 on the cluster; returns the number of roads meshed."""
    work = float(np.sum(units.unit_work))
    batch_work = min(batch_work, max(work / (TASKS_PER_WORKER * fanout.workers), 1.0))
    batches = [units.roads_of_units(batch) for batch in units.batches(spill_grid, batch_work)]
    done = 0
    arguments = ((roads, eps, spill_grid.size, solids, exports) for roads in batches)
    for roads, (records, part) in zip(batches, fanout.map(_batch_task, arguments)):
        _replay(stores, records)
        tally.absorb(part)
        done += len(roads)
        report(done, total_roads)
    return done


def _batch_task(digest, data, name, roads, eps, tile_size, solids, exports):
    from tavf_mapkit.mesh.tiled import _mesh_batch, _Tally

    odr, units = _map_and_units(digest, data, name)
    stores = {store: MemoryStore() for store in STORES}
    tally = _Tally()
    _mesh_batch(odr, units, roads, eps, TileGrid.spill(tile_size), stores, tally, solids, exports)
    return _records(stores), tally


# -- pass 2 ------------------------------------------------------------------------------------------------------

def junction_curbs(fanout, surface, stores: dict, tally, report) -> Callable[[], None]:
    """Pass 2 on the cluster, started: groups of junction clusters, whose first tasks run while the client goes
    on (it places the buildings, pass 3, which reads the same surface and not the curbs). The returned function
    waits for the rest and adds the curbs in the single process's order; pieces are merged by key, so what the
    stores hold does not depend on whether buildings or curbs came first."""
    from tavf_mapkit.mesh.solid_junction_curbs import CONTEXT_REACH
    from tavf_mapkit.mesh.tiled import CLUSTER_GROUP, clusters_in_order

    clusters = clusters_in_order(surface.grid, tally.cluster_box)
    size = batches_for(len(clusters), fanout.workers, CLUSTER_GROUP, TASKS_PER_WORKER)
    groups = [clusters[start:start + size] for start in range(0, len(clusters), size)]

    def arguments():
        for group in groups:
            boxes = {unit: tally.cluster_box[unit] for unit in group}
            yield (group, boxes, _surface_blobs(surface, boxes.values(), CONTEXT_REACH),
                   surface.low, surface.high, surface.reach, surface.size)

    report(0, len(clusters))
    results = fanout.map(_curb_task, arguments())  # submits the first tasks now

    def finish() -> None:
        done = 0
        for group, (records, part) in zip(groups, results):
            _replay(stores, records)
            tally.absorb(part)
            done += len(group)
            report(done, len(clusters))

    return finish


def _surface_blobs(surface, boxes, reach: float) -> dict:
    """{spill tile: stored chunks} of the surface a task around ``boxes`` may look at (``_SurfaceTiles.square``)."""
    keys = set()
    for box in boxes:
        lo, hi = surface.cells(box, reach)
        lo, hi = np.maximum(lo, surface.low), np.minimum(hi, surface.high)
        for i in range(int(lo[0]), int(hi[0]) + 1):
            for j in range(int(lo[1]), int(hi[1]) + 1):
                if (i, j) in surface.store:
                    keys.add((i, j))
    return {key: surface.store.blobs(key) for key in sorted(keys)}


def _curb_task(digest, data, name, group, boxes, blobs, low, high, reach, size):
    from tavf_mapkit.mesh.solid_junction_curbs import CONTEXT_REACH
    from tavf_mapkit.mesh.tiled import (
        _cluster_curbs,
        _SurfaceTiles,
        _Tally,
        curb_surroundings,
        junction_ranks,
    )

    odr, units = _map_and_units(digest, data, name)
    surface = _SurfaceTiles(MemoryStore(blobs), TileGrid.spill(size), reach)
    surface.low, surface.high = low, high  # the whole spill's extent, not only the tiles sent
    stores = {store: MemoryStore() for store in STORES}
    tally = _Tally(cluster_box=dict(boxes))
    rank = worker_cached(("junction ranks", digest), lambda: junction_ranks(odr))
    around = curb_surroundings(odr, units, group, boxes)
    for unit in group:
        _cluster_curbs(odr, units, unit, surface, around, rank, stores, tally, CONTEXT_REACH)
    tally.cluster_box = {}  # the client has them
    return _records(stores), tally


# -- pass 4 ------------------------------------------------------------------------------------------------------

def tile_products(fanout, squares: list, layers_of: dict, grid: TileGrid, fmt: str, exports: bool, canvas,
                  tally):
    """``tiled.TileProduct`` of every square, in order, made on the cluster; their paint added to ``canvas``."""
    size = batches_for(len(squares), fanout.workers, TILES_PER_TASK, TASKS_PER_WORKER)
    groups = [squares[start:start + size] for start in range(0, len(squares), size)]
    paint = None if canvas is None else (tally.low, tally.high)

    def arguments():
        for group in groups:
            blobs = {}
            for name, regrid in layers_of.items():
                keys = sorted({key for square in group for key in regrid.sources.get(square, ())})
                blobs[name] = {key: regrid.store.blobs(key) for key in keys}
            yield group, blobs, grid.origin, grid.size, fmt, exports, paint

    for products, painted in fanout.map(_tiles_task, arguments()):
        if canvas is not None:
            canvas.add_painted(painted)
        yield from products


def _tiles_task(digest, data, name, group, blobs, origin, size, fmt, exports, paint):
    from tavf_mapkit.mesh.preview import PreviewCanvas
    from tavf_mapkit.mesh.tiled import _Regrid, tile_product

    grid = TileGrid(tuple(origin), size)
    spill_grid = TileGrid.spill(size)
    layers_of = {store: _Regrid(MemoryStore(blobs[store]), grid, spill_grid, store) for store in STORES}
    canvas = None if paint is None else PreviewCanvas(*paint)
    products = [tile_product(index, layers_of, grid, fmt, exports, canvas) for index in group]
    return products, (None if canvas is None else canvas.painted())
