"""Units of work of the tiled mesher: which roads are meshed together, in which batch, and near what.

A *unit* is a road outside junctions, or a *junction cluster*: every connecting road of the junctions whose
coarse plan boxes touch (a junction surface is draped on its connecting lanes, and where two junctions touch
they see each other's lanes). Everything the mesher makes of a unit depends on the unit alone, so it comes out
the same whichever other units share its batch; a unit's faces keep the order they have when it is meshed on
its own, and units are ranked by their first road (that order is the canonical order of every output).

Batches are units grouped by the tile grid: units sorted by the tile of their anchor (blocks of BLOCK x BLOCK
tiles, then tiles, row by row), cut at tile boundaries once a batch holds ``max_work`` metres of lane. Memory of
a batch grows with that figure, not with the map.

Coarse boxes (every lane border and the reference line sampled every COARSE_STEP m, grown by BOX_MARGIN, which
covers what the samples cut off a curve) only decide grouping and neighbourhoods: which roads may come near a
junction's curbs. They never shape a mesh.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tavf_mapkit.tilegrid import TileGrid

COARSE_STEP = 5.0        # m of s between samples of the coarse boxes
BOX_MARGIN = 2.0         # m added around every coarse box (chord error of a 5 m step on a 1.6 m radius)
CLUSTER_GAP = 1.0        # m: junctions whose coarse boxes come this close are one cluster
BLOCK = 8                # tiles per side of the blocks that order batches
CHUNK_SAMPLES = 200_000  # samples per pass of the coarse boxes (bounded memory)
MEETING_CHUNK = 256      # roads per step of ``MeshUnits.roads_meeting``


@dataclass(frozen=True, eq=False)
class MeshUnits:
    road_unit: np.ndarray       # (R,) unit of every road; units are numbered in canonical order
    unit_start: np.ndarray      # (U + 1,) CSR offsets into unit_roads
    unit_roads: np.ndarray      # road indices, unit by unit, ascending inside a unit
    road_box: np.ndarray        # (R, 4) coarse plan box (west, south, east, north), margin included
    unit_box: np.ndarray        # (U, 4)
    unit_work: np.ndarray       # (U,) metres of lane (section length x lanes, the reference line at least)
    unit_junctions: tuple       # per unit: the junction ids of a cluster (empty for a plain road)
    # whole-map facts every batch asks for, found once here (a per-batch pass over every road or lane made the
    # mesh stage grow with batches x map, quadratic at region scale):
    road_junction: np.ndarray   # (R,) object: the junction id of a connecting road, "" for any other road
    lane_kind: np.ndarray       # (L,) int16 KIND_CODE of every lane row's type (``kinds.lane_kind_codes``)
    raised_rows: np.ndarray     # (L,) bool: the lane has a non-zero height somewhere (``lanes.raised_lane_rows``)
    in_junction: np.ndarray     # (R,) bool: the road is a connecting road of a junction
    junction_first_road: dict   # junction id -> index of its first connecting road

    @property
    def count(self) -> int:
        return len(self.unit_work)

    def roads_of(self, unit: int) -> np.ndarray:
        return self.unit_roads[self.unit_start[unit]:self.unit_start[unit + 1]]

    def roads_of_units(self, units: np.ndarray) -> np.ndarray:
        """Road indices of several units, ascending."""
        if not len(units):
            return np.zeros(0, dtype=np.int64)
        return np.sort(np.concatenate([self.roads_of(int(u)) for u in units]))

    def is_cluster(self, unit: int) -> bool:
        return bool(self.unit_junctions[unit])

    def anchor(self) -> np.ndarray:
        """(U, 2) centre of every unit's coarse box."""
        return 0.5 * (self.unit_box[:, :2] + self.unit_box[:, 2:])

    def roads_meeting(self, roads: np.ndarray) -> np.ndarray:
        """Roads whose coarse box meets (touching counts) the coarse box of one of ``roads``, ascending."""
        roads = np.asarray(roads, dtype=np.int64)
        if not len(roads):
            return np.zeros(0, dtype=np.int64)
        mine = self.road_box[roads]
        # one pass over the map for the box around all of them, then the exact test on those candidates only
        candidates = self.roads_near(np.concatenate([mine[:, :2].min(axis=0), mine[:, 2:].max(axis=0)]), 0.0)
        b = self.road_box[candidates]
        met = np.zeros(len(candidates), dtype=bool)
        for start in range(0, len(roads), MEETING_CHUNK):  # bounded memory: chunk x candidates booleans
            m = mine[start:start + MEETING_CHUNK]
            met |= np.any((b[None, :, 0] <= m[:, None, 2]) & (b[None, :, 2] >= m[:, None, 0])
                          & (b[None, :, 1] <= m[:, None, 3]) & (b[None, :, 3] >= m[:, None, 1]), axis=0)
        return candidates[met]

    def roads_near(self, box, reach: float) -> np.ndarray:
        """Roads whose coarse box comes within ``reach`` of ``box`` (west, south, east, north), ascending."""
        west, south, east, north = box
        b = self.road_box
        near = ((b[:, 0] <= east + reach) & (b[:, 2] >= west - reach) & (b[:, 1] <= north + reach)
                & (b[:, 3] >= south - reach))
        return np.flatnonzero(near)

    def batches(self, grid: TileGrid, max_work: float) -> list[np.ndarray]:
        """Units in batches: grouped by the tile of ``grid`` (the mesher's spill grid) their anchor is in, at
        most ``max_work`` m of lane per batch (unless one tile alone holds more)."""
        if not self.count:
            return []
        cell = grid.tile_of_points(self.anchor())
        block = np.floor_divide(cell, BLOCK)
        order = np.lexsort((np.arange(self.count), cell[:, 0], cell[:, 1], block[:, 0], block[:, 1]))
        batches, current, work = [], [], 0.0
        for k, unit in enumerate(order.tolist()):
            new_cell = k == 0 or np.any(cell[unit] != cell[order[k - 1]])
            if current and new_cell and work >= max_work:
                batches.append(np.array(current, dtype=np.int64))
                current, work = [], 0.0
            current.append(unit)
            work += float(self.unit_work[unit])
        if current:
            batches.append(np.array(current, dtype=np.int64))
        return batches


def mesh_units(odr) -> MeshUnits:
    """Units, coarse boxes and clusters of a map (a few numpy passes over the map, bounded memory)."""
    from tavf_mapkit.mesh.kinds import lane_kind_codes
    from tavf_mapkit.mesh.lanes import raised_lane_rows

    arrays = odr.arrays
    n_roads = len(odr.roads)
    road_box = coarse_road_boxes(odr)
    junction_of_road = [road.junction if road.in_junction else None for road in odr.roads]
    clusters = _junction_clusters(junction_of_road, road_box)
    # a unit per plain road, one per cluster; ranked by their first road
    key = np.arange(n_roads, dtype=np.int64)
    first_of_cluster: dict[int, int] = {}
    for road, junction in enumerate(junction_of_road):
        if junction is not None:
            cluster = clusters[junction]
            first_of_cluster.setdefault(cluster, road)
            key[road] = first_of_cluster[cluster]
    firsts, road_unit = np.unique(key, return_inverse=True)
    road_unit = road_unit.ravel().astype(np.int64)
    order = np.argsort(road_unit, kind="stable")
    unit_start = np.searchsorted(road_unit[order], np.arange(len(firsts) + 1))
    junctions_of_unit: list[list[str]] = [[] for _ in range(len(firsts))]
    seen = set()
    for road, junction in enumerate(junction_of_road):
        if junction is not None and junction not in seen:
            seen.add(junction)
            junctions_of_unit[road_unit[road]].append(junction)
    unit_box = np.empty((len(firsts), 4))
    for k, reducer in ((0, np.minimum), (1, np.minimum), (2, np.maximum), (3, np.maximum)):
        unit_box[:, k] = reducer.reduceat(road_box[order, k], unit_start[:-1]) if n_roads else 0.0
    lane_count = np.bincount(arrays.lane_section, minlength=len(arrays.section_s0))
    section_work = (arrays.section_end - arrays.section_s0) * np.maximum(lane_count, 1)
    road_work = np.bincount(arrays.section_road, weights=section_work, minlength=n_roads)
    unit_work = np.bincount(road_unit, weights=road_work, minlength=len(firsts))
    road_junction = np.array(["" if j is None else j for j in junction_of_road], dtype=object)
    first_road: dict = {}
    for road, junction in enumerate(junction_of_road):
        if junction is not None:
            first_road.setdefault(junction, road)
    return MeshUnits(road_unit, unit_start, order.astype(np.int64), road_box, unit_box, unit_work,
                     tuple(tuple(j) for j in junctions_of_unit), road_junction, lane_kind_codes(arrays.lane_type),
                     raised_lane_rows(arrays), road_junction != "", first_road)


def coarse_road_boxes(odr) -> np.ndarray:
    """(R, 4) plan box of every road: lane borders and reference line every COARSE_STEP m, grown by
    BOX_MARGIN. A road without a lane section of positive length takes its first geometry's start."""
    from tavf_mapkit.opendrive.sampling import sample_lanes_at, section_samples

    arrays = odr.arrays
    n_roads = len(odr.roads)
    low = np.full((n_roads, 2), np.inf)
    high = np.full((n_roads, 2), -np.inf)
    sections = np.flatnonzero(arrays.section_end - arrays.section_s0 > 0)
    if len(sections):
        per_section = np.floor((arrays.section_end[sections] - arrays.section_s0[sections]) / COARSE_STEP) + 2
        chunk_of = (np.cumsum(per_section) // CHUNK_SAMPLES).astype(np.int64)
        for chunk in np.split(sections, np.flatnonzero(np.diff(chunk_of)) + 1):
            sampling = sample_lanes_at(odr, *section_samples(arrays, COARSE_STEP, True, chunk))
            road = arrays.section_road[sampling.sample_section]
            points = [(road, np.column_stack([sampling.ref_x, sampling.ref_y]))]
            if len(sampling.pair_lane):
                points.append((sampling.road_index, sampling.outer_border_points()[:, :2]))
            for rows, xy in points:
                np.minimum.at(low, rows, xy)
                np.maximum.at(high, rows, xy)
    empty = ~np.isfinite(low[:, 0])
    if np.any(empty):
        table = arrays.geometries
        first = np.clip(np.searchsorted(table.group, np.flatnonzero(empty), side="left"), 0, max(len(table.x) - 1, 0))
        has = len(table.x) > 0
        start = np.column_stack([table.x[first], table.y[first]]) if has else np.zeros((int(empty.sum()), 2))
        start = np.where(np.isfinite(start), start, 0.0)
        low[empty] = start
        high[empty] = start
    return np.column_stack([low - BOX_MARGIN, high + BOX_MARGIN])


def _junction_clusters(junction_of_road: list, road_box: np.ndarray) -> dict[str, int]:
    """junction id -> cluster number: junctions whose boxes (union of their roads' boxes) come within
    CLUSTER_GAP of each other, transitively."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    ids = sorted({j for j in junction_of_road if j is not None})
    if not ids:
        return {}
    number = {j: k for k, j in enumerate(ids)}
    box = np.tile(np.array([np.inf, np.inf, -np.inf, -np.inf]), (len(ids), 1))
    for road, junction in enumerate(junction_of_road):
        if junction is not None:
            k = number[junction]
            box[k, :2] = np.minimum(box[k, :2], road_box[road, :2])
            box[k, 2:] = np.maximum(box[k, 2:], road_box[road, 2:])
    # pairs of overlapping boxes: sweep along x (sorted west edges), then test y
    half = 0.5 * CLUSTER_GAP
    west, south, east, north = box[:, 0] - half, box[:, 1] - half, box[:, 2] + half, box[:, 3] + half
    order = np.argsort(west, kind="stable")
    reach = np.searchsorted(west[order], east[order], side="right")
    a, b = [], []
    for k in range(len(order)):
        others = order[k + 1:reach[k]]
        if len(others):
            i = order[k]
            hit = others[(south[others] <= north[i]) & (north[others] >= south[i]) & (west[others] <= east[i])]
            a.extend([i] * len(hit))
            b.extend(hit.tolist())
    graph = coo_matrix((np.ones(len(a)), (np.array(a, dtype=np.int64), np.array(b, dtype=np.int64))),
                       shape=(len(ids), len(ids)))
    _, label = connected_components(graph, directed=False)
    return {j: int(label[number[j]]) for j in ids}
