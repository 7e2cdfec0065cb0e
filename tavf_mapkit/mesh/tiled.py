"""The tiled mesher: a map of any size in memory bounded by the tile, not the map.

The map is meshed in batches of units (``mesh.units``: roads outside junctions, junction clusters), grouped by
the tile grid. What is made of a unit depends on that unit alone, so the result never depends on how units are
batched. Four passes, each holding one batch or a few tiles at a time:

1. per batch: adaptive samples, lane and junction surfaces, road marks, and the solids of single roads
   (raised-lane curbs, objects, signals); the pieces are spilled to disk by tile (``mesh.spill``), with a key
   per face and vertex that gives their place in the whole map's canonical order;
2. per junction cluster: its curbs, from the spilled surface of the tiles around it;
3. per group of buildings: their passages and ground heights, from the spilled surface around them (the ground
   search widens until the nearest surface vertices are certain);
4. the origin is now known (the middle of all vertices' bounds): the pieces are moved to their tiles of the
   final grid (``tavf_mapkit.tilegrid``), and each tile is merged in canonical order and written -- glTF / OBJ, the
   labelled tile the collision stage reads, its strokes on the preview -- keeping only small per-tile figures.

Files come out the same as exporting the whole map's meshes at once (``export.export_meshes``).
"""

from __future__ import annotations

import json
import shutil
import tempfile
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tavf_mapkit.fileutil import write_text_atomic
from tavf_mapkit.mesh.export import check_export_options, mesh_summary, write_materials
from tavf_mapkit.mesh.labelled import KIND_CODE, SURFACE_KINDS, LabelledMesh, npz_bytes
from tavf_mapkit.mesh.materials import mark_material
from tavf_mapkit.mesh.spill import ChunkStore, Keyed, from_arrays, key_order, keyed_by_group, merge
from tavf_mapkit.mesh.tiles import face_tiles, solid_tiles
from tavf_mapkit.mesh.units import BLOCK
from tavf_mapkit.progress import Progress, Report, reporter
from tavf_mapkit.tilegrid import TileGrid, group_by_tile, origin_of_bounds, tile_name

#: metres of lane per batch: memory of a batch grows with it (about 2 MB per km: AT_krems meshed in batches of
#: 100, 25 and 10 km peaked 204, 90 and 70 MiB above its loaded map), time hardly at all
BATCH_WORK = 20_000.0
LABELLED = "labelled"
TILE_CACHE = 256          # spilled tiles kept merged in memory while curbs and buildings look around ...
TILE_CACHE_BYTES = 64 << 20  # ... and at most this many bytes of them per cache: a city's freeway interchanges
                             # make tiles of megabytes, and 256 of them in each of the five caches held GBs
ROUNDING_MARGIN = 1e-3  # m: far above the rounding of a centroid's tile (1e-9 m at 5,000 km from the origin)
CLUSTER_GROUP = 64        # junction clusters whose surroundings are sampled together
CURBS, JUNCTION_CURBS, OBJECTS, SIGNALS, BUILDINGS = range(5)  # producers, in the order of the scene solids


@dataclass
class _Tally:
    """What the passes keep of the whole map: bounds, counts, facts, the junction clusters' boxes."""

    low: np.ndarray | None = None
    high: np.ndarray | None = None
    kinds: np.ndarray = field(default_factory=lambda: np.zeros(len(SURFACE_KINDS), dtype=np.int64))
    marks: int = 0
    solid_faces: int = 0
    materials: set = field(default_factory=set)
    max_deviation: float = 0.0
    discontinuities: int = 0
    unresolved: int = 0
    junctions: int = 0
    reach: float = 0.0                                       # farthest surface corner from its face's centroid
    cluster_box: dict = field(default_factory=dict)          # unit -> box of its junction faces
    solid_counts: dict = field(default_factory=lambda: {k: 0 for k in ("curb", "object", "signal", "building")})
    skipped: list = field(default_factory=list)              # (key, line)

    def extend(self, vertices: np.ndarray) -> None:
        if not len(vertices):
            return
        low, high = vertices[:, :2].min(axis=0), vertices[:, :2].max(axis=0)
        self._bounds(low, high)

    def _bounds(self, low, high) -> None:
        self.low = low if self.low is None else np.minimum(self.low, low)
        self.high = high if self.high is None else np.maximum(self.high, high)

    def absorb(self, other: _Tally) -> None:
        """Add what a task tallied on its own (``mesh.remote``); absorbed in the order the serial passes would
        have made them, the totals and lists come out the same."""
        if other.low is not None:
            self._bounds(other.low, other.high)
        self.kinds = self.kinds + other.kinds
        self.marks += other.marks
        self.solid_faces += other.solid_faces
        self.materials |= other.materials
        self.max_deviation = max(self.max_deviation, other.max_deviation)
        self.discontinuities += other.discontinuities
        self.unresolved += other.unresolved
        self.junctions += other.junctions
        self.reach = max(self.reach, other.reach)
        self.cluster_box.update(other.cluster_box)
        for kind, count in other.solid_counts.items():
            self.solid_counts[kind] += count
        self.skipped += other.skipped


def write_tiled_mesh(odr, folder: str | Path, eps: float, fmt: str = "glb", tile_size: float = 100.0,
                     osm_path: Path | None = None, solids: bool = True, preview: bool = True,
                     exports: bool = True, batch_work: float = BATCH_WORK, extra: dict | None = None,
                     origin=None, progress: Progress | None = None, fanout=None) -> dict:
    """Mesh the map into ``folder``: tiles/ and road marks (unless ``exports`` is off), labelled/ (surface and
    solids per tile, for the collision world), mesh.json and preview.png. Returns mesh.json's content.
    ``folder`` is one being made, put in place whole by the caller (``mesh.folder.replace_folder``, a build's
    staging folder, a temporary folder): the tile files are written straight into it.
    ``origin``: the origin to use instead of the middle of the meshes' bounds (e.g. another stage's).
    ``progress`` hears of each pass: roads meshed, junction clusters curbed, building groups placed, tiles
    written. ``fanout``: a ``cluster.Fanout``, to run the batches, the junction clusters' curbs and the tiles as
    Dask tasks (``mesh.remote``, which sends the workers this map and its units; the files come out the same)."""
    from tavf_mapkit.mesh.units import mesh_units

    check_export_options(fmt, tile_size)
    if not (eps > 0 and np.isfinite(eps)):
        raise ValueError("eps must be a positive number of metres")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    arrays = odr.arrays
    # implausible roads are refused before anything is sampled, the first of them by road order (as meshing the
    # whole map at once would)
    arrays.budget.check_roads(arrays.section_road[arrays.section_end - arrays.section_s0 > 1e-9])
    units = mesh_units(odr)
    spill = Path(tempfile.mkdtemp(prefix=".spill-", dir=folder))
    stores = {name: ChunkStore(spill / f"{name}.bin") for name in ("surface", "marks", "solids", "whole")}
    tally = _Tally()
    spill_grid = TileGrid.spill(float(tile_size))
    try:
        if fanout is not None:
            from tavf_mapkit.mesh import remote

            fanout = remote.share_map(fanout, odr, units)
        roads_done, report = 0, reporter(progress, "roads")
        if fanout is None:
            for batch in units.batches(spill_grid, batch_work):
                report(roads_done, len(odr.roads))
                roads = units.roads_of_units(batch)
                _mesh_batch(odr, units, roads, eps, spill_grid, stores, tally, solids, exports)
                roads_done += len(roads)
        else:
            roads_done = remote.mesh_batches(fanout, units, batch_work, eps, spill_grid, stores, tally, solids,
                                             exports, report, len(odr.roads))
        report(roads_done, len(odr.roads))
        if solids:
            surface = _SurfaceTiles(stores["surface"], spill_grid, tally.reach)
            if fanout is None:
                _junction_curbs(odr, units, surface, stores, tally, reporter(progress, "junction clusters"))
                _buildings(odr, units, osm_path, surface, stores, tally, reporter(progress, "building groups"))
            else:  # the workers make the curbs while this process places the buildings
                curbs = remote.junction_curbs(fanout, surface, stores, tally,
                                              reporter(progress, "junction clusters"))
                _buildings(odr, units, osm_path, surface, stores, tally, reporter(progress, "building groups"))
                curbs()
            del surface  # its merged tiles are not held under the final grid's own (pass 4)
        origin = origin_of_bounds(tally.low, tally.high) if origin is None else tuple(float(v) for v in origin)
        grid = TileGrid(origin, float(tile_size))
        summary = _write_tiles(odr, folder, fmt, grid, stores, tally, preview, exports, eps, osm_path, solids,
                               extra or {}, reporter(progress, "tiles"), fanout)
    finally:
        for store in stores.values():
            store.close()
        shutil.rmtree(spill, ignore_errors=True)
    return summary


# -- pass 1: batches ---------------------------------------------------------------------------------------

def _mesh_batch(odr, units, roads, eps, spill_grid: TileGrid, stores, tally, solids: bool, marks: bool) -> None:
    from tavf_mapkit.mesh.marks import road_marks
    from tavf_mapkit.mesh.surface import build_road_surface

    surface = build_road_surface(odr, eps, units=units, roads=roads)
    samples = surface.samples
    tally.max_deviation = max(tally.max_deviation, samples.max_deviation)
    tally.discontinuities += samples.discontinuities
    tally.unresolved += samples.unresolved
    tally.junctions += len(surface.junction_footprints)
    mesh = surface.mesh
    keyed = keyed_by_group(mesh, units.road_unit[mesh.road_index])
    if len(mesh.faces):
        corners = mesh.vertices[mesh.faces][:, :, :2]
        tally.reach = max(tally.reach, float(np.max(np.linalg.norm(
            corners - corners.mean(axis=1, keepdims=True), axis=2))))
        junction = mesh.kind == KIND_CODE["junction"]
        if np.any(junction):
            _cluster_boxes(keyed, tally)
    _spill(stores["surface"], keyed, spill_grid, tally, "lanes")
    if marks:
        painted = road_marks(odr, eps, samples, roads=roads)
        _spill(stores["marks"], keyed_by_group(painted, units.road_unit[painted.road_index]), spill_grid, tally,
               "marks")
    if solids:
        _road_solids(odr, units, roads, keyed.mesh, eps, stores, tally, spill_grid)


def _cluster_boxes(keyed: Keyed, tally: _Tally) -> None:
    mesh = keyed.mesh
    junction = np.flatnonzero(mesh.kind == KIND_CODE["junction"])
    unit = keyed.face_key[junction, 0]
    corners = mesh.vertices[mesh.faces[junction]][:, :, :2]
    low, high = corners.min(axis=1), corners.max(axis=1)
    for u in np.unique(unit).tolist():
        mine = unit == u
        tally.cluster_box[u] = np.concatenate([low[mine].min(axis=0), high[mine].max(axis=0)])


def _spill(store: ChunkStore, keyed: Keyed, spill_grid: TileGrid, tally: _Tally, layer: str) -> None:
    """Chunks of a keyed mesh by spill tile (the tile of each face's centroid: the final grid is not known yet)."""
    mesh = keyed.mesh
    if not len(mesh.faces):
        return
    tally.extend(mesh.vertices)
    if layer == "lanes":
        tally.kinds += np.bincount(mesh.kind.astype(np.int64), minlength=len(SURFACE_KINDS))
    elif layer == "marks":
        tally.marks += len(mesh.faces)
    else:
        tally.solid_faces += len(mesh.faces)
    for index, faces in group_by_tile(face_tiles(spill_grid, mesh)).items():
        store.add(index, keyed.select(faces).arrays())


def _road_solids(odr, units, roads, surface: LabelledMesh, eps, stores, tally, spill_grid: TileGrid) -> None:
    """Curbs of raised lanes, objects and signals: each road's own, keyed (producer, road, number)."""
    from tavf_mapkit.mesh.solid_curbs import curb_solids
    from tavf_mapkit.mesh.solid_objects import object_solids
    from tavf_mapkit.mesh.solid_signals import signal_solids

    arrays = odr.arrays
    raised = set(np.unique(arrays.section_road[arrays.lane_section[units.raised_rows]]).tolist())
    order = np.argsort(surface.road_index, kind="stable")
    bounds = np.searchsorted(surface.road_index[order], [roads, roads + 1])
    made, skipped = [], []
    for k, road in enumerate(np.asarray(roads).tolist()):
        producers = []
        if road in raised:
            faces = np.sort(order[bounds[0][k]:bounds[1][k]])
            producers.append((CURBS, lambda faces=faces: curb_solids(odr, surface.select(faces))))
        if odr.roads[road].objects:
            producers.append((OBJECTS, lambda road=road: object_solids(odr, eps, [road])))
        if odr.roads[road].signals:
            producers.append((SIGNALS, lambda road=road: signal_solids(odr, eps, [road])))
        for producer, make in producers:
            built, missing = make()
            made += [((producer, road, n), solid) for n, solid in enumerate(built)]
            skipped += [((producer, road, n), line) for n, line in enumerate(missing)]
    _spill_solids(made, stores, tally, spill_grid)
    tally.skipped += skipped


def _spill_solids(made: list, stores, tally: _Tally, spill_grid: TileGrid) -> None:
    """Solids keyed (producer, primary, number): their faces by tile of face (the exported meshes), and each
    solid whole by tile of its centre (the collision world)."""
    if not made:
        return
    keys = np.array([key for key, _ in made], dtype=np.int64)
    solids = [solid for _, solid in made]
    for solid in solids:
        tally.solid_counts[solid.kind] += 1
    meshes = [solid.mesh for solid in solids]
    face_key = np.concatenate([np.column_stack([np.repeat(keys[k:k + 1], len(m.faces), axis=0),
                                                np.arange(len(m.faces))]) for k, m in enumerate(meshes)])
    vertex_key = np.concatenate([np.column_stack([np.repeat(keys[k:k + 1], len(m.vertices), axis=0),
                                                  np.arange(len(m.vertices))]) for k, m in enumerate(meshes)])
    _spill(stores["solids"], Keyed(LabelledMesh.concatenate(meshes), face_key, vertex_key), spill_grid, tally,
           "solids")
    for index, members in group_by_tile(solid_tiles(spill_grid, meshes)).items():
        stores["whole"].add(index, _solid_arrays([solids[k] for k in members], keys[members]))


def _solid_arrays(solids: list, keys: np.ndarray) -> dict:
    from tavf_mapkit.mesh.solids import SceneSolids

    return {**SceneSolids(tuple(solids), ()).arrays(), "solid_key": keys}


# -- passes 2 and 3: what needs the surface around it ------------------------------------------------------------

class _TileCache:
    """Merged spill tiles, least recently used first out: at most TILE_CACHE of them and TILE_CACHE_BYTES of
    their arrays. Only the time depends on it (a tile that left is merged again when asked for)."""

    def __init__(self):
        self.entries: OrderedDict = OrderedDict()
        self.sizes: dict = {}
        self.bytes = 0

    def get(self, key):
        entry = self.entries.get(key)
        if entry is not None:
            self.entries.move_to_end(key)
        return entry

    def __contains__(self, key) -> bool:
        return key in self.entries

    def put(self, key, entry) -> None:
        self.entries[key] = entry
        self.sizes[key] = _nbytes(entry)
        self.bytes += self.sizes[key]
        while len(self.entries) > 1 and (len(self.entries) > TILE_CACHE or self.bytes > TILE_CACHE_BYTES):
            old, _ = self.entries.popitem(last=False)
            self.bytes -= self.sizes.pop(old)


def _nbytes(value) -> int:
    """Bytes of the arrays in a cache entry (meshes, keys, dicts and lists of them)."""
    if value is None:
        return 0
    if isinstance(value, np.ndarray):
        return value.nbytes
    if isinstance(value, Keyed):
        return _nbytes(value.mesh) + value.face_key.nbytes + value.vertex_key.nbytes
    if isinstance(value, dict):
        return sum(_nbytes(item) for item in value.values())
    if isinstance(value, (list, tuple)):
        return sum(_nbytes(item) for item in value)
    if hasattr(value, "__dataclass_fields__"):
        return sum(_nbytes(getattr(value, name)) for name in value.__dataclass_fields__)
    return 0


class _SurfaceTiles:
    """The spilled road surface, merged per spill tile on demand (a bounded cache)."""

    def __init__(self, store: ChunkStore, grid: TileGrid, reach: float):
        self.store = store
        self.grid = grid
        self.size = grid.size
        self.reach = reach
        self.cache = _TileCache()
        keys = np.array(store.keys(), dtype=np.int64).reshape(-1, 2)
        self.low = keys.min(axis=0) if len(keys) else np.zeros(2, dtype=np.int64)
        self.high = keys.max(axis=0) if len(keys) else np.zeros(2, dtype=np.int64)

    def _tile(self, index) -> Keyed | None:
        if index in self.cache:
            return self.cache.get(index)
        merged = merge([from_arrays(data, False) for data in self.store.get(index)])
        self.cache.put(index, merged)
        return merged

    def cells(self, box, grow: float) -> tuple[np.ndarray, np.ndarray]:
        """First and last spill tile holding faces that may come within ``grow`` of ``box``."""
        return self.grid.tiles_touching(box, grow + self.reach)

    def square(self, lo, hi) -> Keyed | None:
        """The surface of the spill tiles lo..hi (inclusive), in canonical order."""
        lo, hi = np.maximum(lo, self.low), np.minimum(hi, self.high)
        parts = []
        for i in range(int(lo[0]), int(hi[0]) + 1):
            for j in range(int(lo[1]), int(hi[1]) + 1):
                if (i, j) in self.store:
                    part = self._tile((i, j))
                    if part is not None:
                        parts.append(part)
        return merge(parts)

    def vertices(self, lo, hi) -> np.ndarray:
        """(n, 3) every surface vertex of the spill tiles lo..hi (inclusive), each once."""
        lo, hi = np.maximum(lo, self.low), np.minimum(hi, self.high)
        points, keys = [], []
        for i in range(int(lo[0]), int(hi[0]) + 1):
            for j in range(int(lo[1]), int(hi[1]) + 1):
                if (i, j) in self.store:
                    part = self._tile((i, j))
                    if part is not None:
                        points.append(part.mesh.vertices)
                        keys.append(part.vertex_key)
        if not points:
            return np.zeros((0, 3))
        keys = np.concatenate(keys)
        _, first = np.unique(keys, axis=0, return_index=True)
        return np.concatenate(points)[np.sort(first)]

    def covers_all(self, lo, hi) -> bool:
        return bool(np.all(lo <= self.low) and np.all(hi >= self.high))


def _junction_curbs(odr, units, surface: _SurfaceTiles, stores, tally: _Tally, report: Report) -> None:
    """Pass 2: the curbs of every junction cluster, from the surface around it; clusters in groups that share
    one sampling of the lanes around them (a cluster's curbs depend on its own surroundings only)."""
    from tavf_mapkit.mesh.solid_junction_curbs import CONTEXT_REACH

    junction_rank = junction_ranks(odr)
    clusters = clusters_in_order(surface.grid, tally.cluster_box)
    around = None
    for start in range(0, len(clusters), CLUSTER_GROUP):
        group = clusters[start:start + CLUSTER_GROUP]
        around = curb_surroundings(odr, units, group, tally.cluster_box, around)
        for k, unit in enumerate(group):
            report(start + k, len(clusters))
            _cluster_curbs(odr, units, unit, surface, around, junction_rank, stores, tally, CONTEXT_REACH)
    report(len(clusters), len(clusters))


def junction_ranks(odr) -> dict:
    """junction id -> its rank among the map's junction ids (the key of its curbs)."""
    return {j: k for k, j in enumerate(sorted(junction.id for junction in odr.junctions))}


def clusters_in_order(spill_grid: TileGrid, cluster_box: dict) -> list:
    """Junction clusters by the spill tile of their south-west corner, row by row (clusters near each other
    share tiles); ties keep the order in which the batches found them."""
    corner_tile = {u: spill_grid.tile_of_point(*box[:2]) for u, box in cluster_box.items()}
    return sorted(cluster_box, key=lambda u: corner_tile[u][::-1])


def curb_surroundings(odr, units, group, cluster_box: dict, before=None):
    """One sampling of the lanes around a group of junction clusters (``CurbSurroundings``); ``before``: the
    group before's, whose lanes this group shares are not sampled again (groups follow each other along rows
    of tiles, so each road is sampled about once instead of once per group that comes near it)."""
    from tavf_mapkit.mesh.solid_junction_curbs import ROAD_REACH, CurbSurroundings

    roads = np.unique(np.concatenate([units.roads_near(cluster_box[u], ROAD_REACH) for u in group]))
    return CurbSurroundings(odr, roads, before)


def _cluster_curbs(odr, units, unit, surface, around, junction_rank, stores, tally, reach) -> None:
    """The curbs of one cluster, keyed (producer, junction rank, number in the junction)."""
    from tavf_mapkit.mesh.solid_junction_curbs import cluster_curb_solids

    context = surface.square(*surface.cells(tally.cluster_box[unit], reach))
    mask = (context.mesh.kind == KIND_CODE["junction"]) & (context.face_key[:, 0] == unit)
    made, count = [], {}
    for (junction, _, _), solid, line in cluster_curb_solids(odr, context.mesh, mask, units, around):
        number = count[junction] = count.get(junction, -1) + 1
        key = (JUNCTION_CURBS, junction_rank.get(junction, len(junction_rank)), number)
        if solid is not None:
            made.append((key, solid))
        else:
            tally.skipped.append((key, line))
    _spill_solids(made, stores, tally, surface.grid)


def _buildings(odr, units, osm_path, surface: _SurfaceTiles, stores, tally: _Tally, report: Report) -> None:
    """Pass 3: OSM buildings, in groups by block of tiles, each cut where it stands on a drivable lane or in
    a driving lane's swept path and standing on the lowest of its nearest road-surface vertices."""
    from tavf_mapkit.mesh.kinds import DRIVABLE_KINDS
    from tavf_mapkit.mesh.solid_buildings import building_parts, extrude_building, ground_point, passage_pieces
    from tavf_mapkit.mesh.solid_kit import SolidError
    from tavf_mapkit.mesh.swept_path import REACH, centre_pieces

    if osm_path is None:
        return
    if odr.georeference is None:
        tally.skipped.append(((BUILDINGS, -2, 0), f"{osm_path}: no geoReference in the OpenDRIVE, buildings "
                                                   "cannot be placed"))
        return
    parts, skipped = building_parts(odr, osm_path)
    tally.skipped += [((BUILDINGS, -1, n), line) for n, line in enumerate(skipped)]
    if not parts:
        return
    drivable = [KIND_CODE[k] for k in DRIVABLE_KINDS]
    boxes = np.array([part[1].bounds for part in parts])
    block = TileGrid.spill(surface.size * BLOCK).tile_of_boxes(boxes[:, :2], boxes[:, 2:])
    groups = sorted(group_by_tile(block[:, [1, 0]]).items())
    for done, (_, members) in enumerate(groups):
        report(done, len(groups))
        box = np.concatenate([boxes[members, :2].min(axis=0), boxes[members, 2:].max(axis=0)])
        # only drivable faces that reach into the group's box can cut a passage
        context = surface.square(*surface.cells(box, 0.0))
        mesh = None
        if context is not None:
            plan = context.mesh.vertices[context.mesh.faces][:, :, :2]
            near = (np.all(plan.min(axis=1) <= box[2:], axis=1) & np.all(plan.max(axis=1) >= box[:2], axis=1)
                    & np.isin(context.mesh.kind, drivable))
            mesh = context.mesh.select(np.flatnonzero(near))
        # the swept paths that can reach the group: of the roads whose coarse box (which holds their lanes)
        # comes within a swept path's reach of it; a swept piece depends on its own lane alone
        swept = centre_pieces(odr, units.roads_near(box, REACH))
        pieces = passage_pieces([parts[k] for k in members], mesh, members.tolist(), swept)
        points = np.array([ground_point(polygon) for _, _, polygon, _ in pieces]).reshape(-1, 2)
        heights = _ground_heights(surface, points)
        made, previous, count = [], None, 0
        for (number, where, polygon, extent), z in zip(pieces, heights.tolist()):
            count = count + 1 if number == previous else 0  # the pieces of a part come one after another
            previous = number
            key = (BUILDINGS, number, count)
            try:
                made.append((key, extrude_building(polygon, extent, lambda x, y, z=z: z, where)))
            except SolidError as error:
                tally.skipped.append((key, f"{where}: {error}"))
        _spill_solids(made, stores, tally, surface.grid)
    report(len(groups), len(groups))


def _ground_heights(surface: _SurfaceTiles, points: np.ndarray) -> np.ndarray:
    """``solid_buildings.ground_heights`` of the whole map's surface at plan points, from the spilled tiles.
    The k nearest vertices among loaded tiles are the map's when they are closer than anything not loaded can
    be (a vertex lies within ``reach`` of its face's centroid); their distance bounds where the true ones are,
    so one more, larger square settles every other point."""
    from scipy.spatial import cKDTree

    from tavf_mapkit.mesh.solid_buildings import GROUND_NEIGHBOURS

    out = np.zeros(len(points))
    todo = np.arange(len(points))
    if not len(points):
        return out
    grow = surface.size
    box = np.concatenate([points.min(axis=0), points.max(axis=0)])
    while len(todo):
        lo, hi = surface.cells(box, grow)
        vertices = surface.vertices(lo, hi)
        complete = surface.covers_all(lo, hi)
        if not len(vertices):
            if complete:
                return out  # no surface at all: the ground is 0
            grow = 3 * grow + surface.size
            continue
        k = min(GROUND_NEIGHBOURS, len(vertices))
        q = points[todo]
        distance, index = cKDTree(vertices[:, :2]).query(q, k=k)
        distance, index = distance.reshape(len(todo), k), index.reshape(len(todo), k)
        west, south = surface.grid.tile_bounds(lo)[:2]
        east, north = surface.grid.tile_bounds(hi)[2:]
        inside = np.minimum(q - [west, south], [east, north] - q).min(axis=1) - surface.reach
        settled = complete | ((k == GROUND_NEIGHBOURS) & (distance.max(axis=1) <= inside))
        out[todo[settled]] = vertices[index[settled], 2].min(axis=1)
        if k == GROUND_NEIGHBOURS and np.any(~settled):
            # the true nearest lie within the distance found: a square that holds those discs settles them
            need = distance[~settled].max(axis=1)[:, None]
            box = np.concatenate([(q[~settled] - need).min(axis=0), (q[~settled] + need).max(axis=0)])
            grow = 0.0
        else:
            grow = 3 * grow + surface.size
        todo = todo[~settled]
    return out


# -- pass 4: the final grid ----------------------------------------------------------------------------------

def _write_tiles(odr, folder: Path, fmt, grid: TileGrid, stores, tally: _Tally, preview: bool, exports: bool,
                 eps: float, osm_path, solids: bool, extra: dict, report: Report, fanout=None) -> dict:
    from tavf_mapkit.mesh.marks import MARK_COLOURS
    from tavf_mapkit.mesh.preview import PreviewCanvas

    spill_grid = TileGrid.spill(grid.size)
    layers_of = {name: _Regrid(stores[name], grid, spill_grid, name) for name in stores}
    canvas = PreviewCanvas(tally.low, tally.high) if preview else None
    (folder / LABELLED).mkdir(exist_ok=True)
    if exports:
        (folder / "tiles").mkdir(exist_ok=True)
    tile_entries, labelled, indices = [], [], []
    # block by block, so that the spill tiles around a block are read once; files and lists do not depend on it
    every = set().union(*(regrid.tiles() for regrid in layers_of.values()))
    squares = sorted(every, key=lambda t: (t[1] // BLOCK, t[0] // BLOCK, t[1], t[0]))
    if fanout is None:
        products = (tile_product(index, layers_of, grid, fmt, exports, canvas) for index in squares)
    else:
        from tavf_mapkit.mesh.remote import tile_products

        products = tile_products(fanout, squares, layers_of, grid, fmt, exports, canvas, tally)
    report(0, len(every))
    # ``folder`` is being made (a build's or ``mapkit mesh``'s staging folder, the collision stage's scratch), and is
    # put in place whole: the tiles are written straight in, not each beside itself and renamed (two opens, a
    # chmod and a rename per file were a tenth of the stage); mesh.json, the folder's marker, still comes last
    for done, product in enumerate(products, 1):
        tally.materials.update(product.materials)
        if product.tile is not None:
            relative, data, entry = product.tile
            (folder / relative).write_bytes(data)
            tile_entries.append(entry)
        if product.labelled is not None:
            name = tile_name(product.index)
            (folder / LABELLED / f"{name}.npz").write_bytes(product.labelled)
            labelled.append(name)
            indices.append([int(product.index[0]), int(product.index[1])])
        report(done, len(every))  # squares that may hold a piece: more than the tiles written
    tile_entries.sort(key=lambda entry: tuple(entry["index"]))
    order = sorted(range(len(indices)), key=lambda k: tuple(indices[k]))
    labelled, indices = [labelled[k] for k in order], [indices[k] for k in order]
    if exports and fmt == "obj":
        write_materials(folder, tally.materials)
    kinds = tally.kinds
    junction, curb = int(kinds[KIND_CODE["junction"]]), int(kinds[KIND_CODE["curb"]])
    surface_faces = int(kinds.sum())
    triangles = {"lanes": surface_faces - junction - curb, "junctions": junction, "curb_faces": curb,
                 "marks": tally.marks, "solids": tally.solid_faces,
                 "total": surface_faces + tally.marks + tally.solid_faces}
    skipped = [line for _, line in sorted(tally.skipped, key=lambda item: item[0])]
    buildings_from = None if osm_path is None else Path(osm_path).name
    from tavf_mapkit.world.build import world_georeference

    index_json = {"eps": eps, "tile_size": grid.size, "origin": list(grid.origin), "tiles": labelled,
                  "indices": indices, "georeference": world_georeference(odr.header),
                  "solids": solids, "solid_counts": tally.solid_counts, "skipped": skipped,
                  "buildings_from": buildings_from}
    write_text_atomic(folder / LABELLED / "index.json", json.dumps(index_json, indent=1) + "\n")
    facts = {
        "eps": eps,
        "deviation": {
            "max_m": round(tally.max_deviation, 6),
            "method": "largest distance between mesh and exact OpenDRIVE point at the same (s, t), at 1/4, 1/2 "
                      "and 3/4 of every segment on every lane border and quad diagonal",
            "discontinuities": tally.discontinuities,
            "unresolved_segments": tally.unresolved,
        },
        "junctions": tally.junctions,
        "mark_colours": list(MARK_COLOURS),
        "solids": solids,
        # the labelled surface and the scene solids per tile, so the collision stage can reuse them
        "labelled": {"folder": LABELLED, "eps": eps, "tile_size": grid.size, "solids": solids,
                     "buildings_from": buildings_from},
        **extra,
    }
    summary = mesh_summary(fmt, grid, tile_entries, triangles, tally.materials, facts)
    if canvas is not None:
        canvas.save(folder / "preview.png")
        summary["preview"] = "preview.png"
    write_text_atomic(folder / "mesh.json", json.dumps(summary, indent=2) + "\n")
    return summary


class _Regrid:
    """The spilled pieces of one store seen through the final grid: each spill tile is read and merged once
    (kept in a bounded cache) and its faces -- or whole solids -- grouped by the final tile they belong to.
    A final tile takes its pieces from the few spill tiles around it."""

    def __init__(self, store: ChunkStore, grid: TileGrid, spill_grid: TileGrid, name: str):
        self.store, self.grid, self.name = store, grid, name
        self.cache = _TileCache()
        self.sources: dict = {}  # final tile -> spill tiles that may hold pieces of it
        for key in store.keys():
            # the final tiles the spill tile's square reaches into. A piece is in a spill tile by its centroid
            # (a solid: its box's centre), the same number that puts it in a final tile, and tile_of_points is
            # monotone: it lies in the square up to rounding, so ROUNDING_MARGIN past its edges suffices. (A
            # whole tile more on each side made every final tile read 16 spill tiles instead of 4: a Dask task
            # of 64 final tiles merged twice the spill tiles it needs, and took the empty ring around the map.)
            low, high = grid.tiles_touching(spill_grid.tile_bounds(key), ROUNDING_MARGIN)
            for i in range(int(low[0]), int(high[0]) + 1):
                for j in range(int(low[1]), int(high[1]) + 1):
                    self.sources.setdefault((i, j), []).append(key)

    def tiles(self) -> set:
        return set(self.sources)

    def _load(self, key):
        if key in self.cache:
            return self.cache.get(key)
        chunks = self.store.get(key)
        if self.name == "whole":
            from tavf_mapkit.mesh.solids import SceneSolids

            groups = {}
            for data in chunks:
                solids = SceneSolids.from_arrays(data).solids  # once per chunk, not once per tile it reaches
                for tile, members in group_by_tile(_solid_tiles(self.grid, data)).items():
                    groups.setdefault(tile, []).append(
                        _solid_arrays([solids[k] for k in members.tolist()], data["solid_key"][members]))
            entry = (None, groups)
        else:
            merged = merge([from_arrays(data, self.name == "marks") for data in chunks])
            entry = (merged, group_by_tile(face_tiles(self.grid, merged.mesh)) if merged is not None else {})
        self.cache.put(key, entry)
        return entry

    def parts(self, tile) -> list:
        """Keyed pieces (or, for whole solids, solid arrays) of a final tile."""
        out = []
        for key in self.sources.get(tile, ()):
            merged, groups = self._load(key)
            if tile in groups:
                out.extend(groups[tile]) if merged is None else out.append(merged.select(groups[tile]))
        return out




def _solid_tiles(grid: TileGrid, data: dict) -> np.ndarray:
    """The tile of each solid of a spilled chunk (of its bounding box's centre, as ``mesh.tiles.solid_tiles``)."""
    counts = np.asarray(data["solid_vertices"], dtype=np.int64)
    vertices = data["vertices"]
    if not len(counts):
        return np.zeros((0, 2), dtype=np.int64)
    if np.any(counts <= 0):
        raise ValueError("a spilled solid without vertices")
    starts = np.cumsum(counts) - counts
    # each solid's vertices are one span: its box is a min and max reduced over that span
    return grid.tile_of_boxes(np.minimum.reduceat(vertices, starts, axis=0),
                              np.maximum.reduceat(vertices, starts, axis=0))


@dataclass
class TileProduct:
    """What a square of the final grid gives: materials used, its tile file (relative path, bytes, mesh.json
    entry) and its labelled tile's bytes, each None when the square holds nothing of it."""

    index: tuple
    materials: set
    tile: tuple | None
    labelled: bytes | None


def tile_product(index, layers_of: dict, grid: TileGrid, fmt: str, exports: bool, canvas) -> TileProduct:
    """Merge one square's pieces (``_Regrid`` per store) in canonical order, paint them on ``canvas`` (a
    PreviewCanvas or None) and make its files' bytes."""
    from tavf_mapkit.mesh.export import tile_file
    from tavf_mapkit.mesh.marks import MARK_COLOURS
    from tavf_mapkit.mesh.preview import group_code

    layers = [(layer, merge(layers_of[name].parts(index)))
              for layer, name in (("lanes", "surface"), ("marks", "marks"), ("solids", "solids"))]
    members = []
    for layer, keyed in layers:
        if keyed is None:
            continue
        mesh = keyed.mesh
        codes = mesh.colour if layer == "marks" else mesh.kind
        for code in np.unique(codes).tolist():
            material = mark_material(MARK_COLOURS[code]) if layer == "marks" else SURFACE_KINDS[code]
            members.append((layer, material, mesh.select(np.flatnonzero(codes == code))))
    tile = tile_file(fmt, grid, index, members) if members and exports else None
    if canvas is not None:
        for layer, material, mesh in members:
            canvas.paint(layer, material, group_code(layer, material), mesh)
    whole = layers_of["whole"].parts(index)
    surface = layers[0][1]
    labelled = _labelled_bytes(surface, whole) if surface is not None or whole else None
    return TileProduct(tuple(int(v) for v in index), {material for _, material, _ in members}, tile, labelled)


def _labelled_bytes(surface: Keyed | None, whole: list[dict]) -> bytes:
    """labelled/tile_I_J.npz: the tile's road surface (faces by centroid) and its solids (by centre), both in
    canonical order."""
    from tavf_mapkit.mesh.solids import SceneSolids

    arrays = {}
    if surface is not None:
        mesh = surface.mesh
        arrays.update({f"surface_{name}": getattr(mesh, name) for name in LabelledMesh._ARRAYS})
    if whole:
        solids, keys = [], []
        for data in whole:
            solids += SceneSolids.from_arrays(data).solids
            keys.append(data["solid_key"])
        keys = np.concatenate(keys)
        order = key_order(keys)
        arrays.update({f"solids_{name}": value for name, value in
                       SceneSolids(tuple(solids[k] for k in order.tolist()), ()).arrays().items()
                       if name != "skipped"})
    return npz_bytes(arrays)


def read_labelled_index(folder: str | Path) -> dict:
    """labelled/index.json: eps, tile size, origin, tile names and indices, solid counts, skipped parts."""
    return json.loads((Path(folder) / "index.json").read_text(encoding="utf-8"))


def read_labelled_tile(path: str | Path | bytes):
    """(LabelledMesh surface or None, SceneSolids) of one labelled tile (its path, or the file's bytes)."""
    from tavf_mapkit.mesh.solids import SceneSolids
    from tavf_mapkit.npzfile import read_npz

    arrays = read_npz(path)  # np.load's arrays, without its per-array cost (a build reads tens of thousands)
    surface = None
    if "surface_faces" in arrays:
        surface = LabelledMesh(*(arrays.get(f"surface_{name}") for name in LabelledMesh._ARRAYS))
    return surface, SceneSolids.from_arrays(arrays, prefix="solids_")
