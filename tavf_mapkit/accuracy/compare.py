"""Compare a built OpenDRIVE network with a reference (OpenDRIVE or SUMO) on their overlap.

Both go through their own georeference into one metric CRS (a transverse Mercator centred on the build).
Figures (driving lanes unless said otherwise):
- hausdorff: symmetric Hausdorff distance of lane centre lines and of road centre lines (metres);
- offset: each build lane sample paired with the nearest reference lane sample of the same driving direction;
  mean / median / 95th percentile of the distance where paired within 5 m, and the paired share of length;
- precision (share of the build's lane length within r of the reference's lanes of the same type) and recall
  (share of the reference's length within r of the build), r = 0.5, 1, 2, 3, 5 m, overall and per lane type;
- fitted_transform: the similarity transform that explains BUILD relative to REFERENCE (dx east, dy north);
- topology: junctions inside the overlap, largest strongly connected share of driving lane length, dead ends.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tavf_mapkit.accuracy.networks import CommonFrame, Network, load_network, load_opendrive_network
from tavf_mapkit.accuracy.polylines import LineSamples
from tavf_mapkit.accuracy.transform import DIRECTION_WEIGHT_M, direction_tree, fit_similarity, paired
from tavf_mapkit.errors import InputError

BUFFERS_M = (0.5, 1.0, 2.0, 3.0, 5.0)
PAIR_DISTANCE_M = 5.0


@dataclass(frozen=True, eq=False)
class Comparison:
    report: dict
    build: Network = field(repr=False)
    reference: Network = field(repr=False)
    frame: CommonFrame = field(repr=False)
    build_in: np.ndarray = field(repr=False)       # mask of build lane samples inside the overlap
    build_offset: np.ndarray = field(repr=False)   # distance of each build lane sample to the reference lanes
    overlap: Overlap = field(repr=False)

    def to_dict(self) -> dict:
        return self.report


class Overlap:
    """Where both networks have roads: cells of a grid within ``reach`` of a lane of each network (and inside
    the user's area). A street only one network has counts when the other has roads nearby, so a missing
    street lowers recall, while districts only one network covers are left out."""

    def __init__(self, build: LineSamples, reference: LineSamples, area, frame, cell: float = 25.0,
                 reach: float = 100.0):
        from scipy.ndimage import binary_dilation

        xs = np.r_[build.x, reference.x]
        ys = np.r_[build.y, reference.y]
        self.cell = cell
        self.origin = (float(xs.min()) - reach - cell, float(ys.min()) - reach - cell)
        shape = (int((xs.max() - self.origin[0] + reach) // cell) + 2, int((ys.max() - self.origin[1] + reach) // cell) + 2)
        radius = int(np.ceil(reach / cell))
        yy, xx = np.mgrid[-radius:radius + 1, -radius:radius + 1]
        disk = xx ** 2 + yy ** 2 <= radius ** 2
        masks = []
        for samples in (build, reference):
            grid = np.zeros(shape, dtype=bool)
            i, j = self._cells(samples.x, samples.y)
            grid[i, j] = True
            masks.append(binary_dilation(grid, structure=disk))
        self.grid = masks[0] & masks[1]
        self.area = area
        self.frame = frame

    def _cells(self, x, y):
        i = np.clip(((np.asarray(x) - self.origin[0]) // self.cell).astype(np.int64), 0, None)
        j = np.clip(((np.asarray(y) - self.origin[1]) // self.cell).astype(np.int64), 0, None)
        return i, j

    def contains(self, x, y) -> np.ndarray:
        x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        i, j = self._cells(x, y)
        inside = np.zeros(len(x), dtype=bool)
        valid = (i < self.grid.shape[0]) & (j < self.grid.shape[1])
        inside[valid] = self.grid[i[valid], j[valid]]
        if self.area is not None and inside.any():
            lon, lat = self.frame.to_lonlat(x[inside], y[inside])
            inside[np.flatnonzero(inside)] = self.area.contains(np.asarray(lon), np.asarray(lat))
        return inside

    @property
    def area_km2(self) -> float:
        return float(self.grid.sum()) * self.cell ** 2 / 1e6

    def bounds(self) -> tuple[float, float, float, float] | None:
        i, j = np.nonzero(self.grid)
        if not len(i):
            return None
        return (self.origin[0] + i.min() * self.cell, self.origin[1] + j.min() * self.cell,
                self.origin[0] + (i.max() + 1) * self.cell, self.origin[1] + (j.max() + 1) * self.cell)


def _share(distance: np.ndarray, weight: np.ndarray) -> dict:
    total = float(weight.sum())
    return {f"{r:g}": (round(float(weight[distance <= r].sum()) / total, 4) if total else None) for r in BUFFERS_M}


def _round(value, digits=3):
    return None if value is None or not np.isfinite(value) else round(float(value), digits)


def _paired_offsets(build: LineSamples, reference: LineSamples) -> np.ndarray:
    """Distance from each build sample to the reference line of the same driving direction (inf if none)."""
    if not len(build) or not len(reference):
        return np.full(len(build), np.inf)
    index = paired(direction_tree(reference), build.x, build.y, build.heading)
    same_direction = np.cos(build.heading - reference.heading[index]) > np.cos(np.radians(45))
    # exact distance to that reference line: the two segments beside the paired sample
    n = len(reference)
    best = np.full(len(build), np.inf)
    for offset in (-1, 0):
        a = np.clip(index + offset, 0, n - 1)
        b = np.clip(a + 1, 0, n - 1)
        b = np.where((reference.line[a] == reference.line[b]) & (a != b), b, a)
        dx, dy = reference.x[b] - reference.x[a], reference.y[b] - reference.y[a]
        u = np.clip(((build.x - reference.x[a]) * dx + (build.y - reference.y[a]) * dy)
                    / np.maximum(dx * dx + dy * dy, 1e-18), 0.0, 1.0)
        best = np.minimum(best, np.hypot(build.x - reference.x[a] - u * dx, build.y - reference.y[a] - u * dy))
    return np.where(same_direction, best, np.inf)


def compare_networks(build_path, reference_path, area=None, step: float = 1.0) -> Comparison:
    """Compare BUILD (OpenDRIVE) with REFERENCE (OpenDRIVE or SUMO .net.xml[.gz]); ``area`` is an osm Area."""
    from tavf_mapkit.sumonet import is_sumo_net

    if is_sumo_net(build_path):
        raise InputError("the build must be an OpenDRIVE file (.xodr); a SUMO network can be the reference",
                         file=str(build_path))

    def frame_for(lon, lat):
        if not len(lon):
            raise InputError("the build has no lanes", file=str(build_path))
        return CommonFrame(0.5 * (float(lon.min()) + float(lon.max())), 0.5 * (float(lat.min()) + float(lat.max())))

    build, frame = load_opendrive_network(str(build_path), frame_for, step)
    reference = load_network(reference_path, frame, step)
    overlap = Overlap(build.lanes, reference.lanes, area, frame)
    b_in, r_in = overlap.contains(build.lanes.x, build.lanes.y), overlap.contains(reference.lanes.x, reference.lanes.y)
    bl, rl = build.lanes.subset(b_in), reference.lanes.subset(r_in)

    report: dict = {
        "build": str(build_path), "reference": str(reference_path), "reference_kind": reference.kind,
        "crs": frame.proj, "step_m": step,
        "overlap": {"area_km2": round(overlap.area_km2, 4), "definition": "grid cells of 25 m within 100 m of "
                    "lanes of both networks" + (", inside the given area" if area is not None else "")},
    }
    bounds = overlap.bounds()
    if bounds is not None:
        west, south, east, north = bounds
        lon, lat = frame.to_lonlat(np.array([west, east]), np.array([south, north]))
        report["overlap"]["bounds_wgs84"] = [round(float(v), 6) for v in (lon[0], lat[0], lon[1], lat[1])]
    if not len(bl) or not len(rl):
        raise InputError(f"the build and {reference_path} do not overlap"
                         + (" inside the given area" if area is not None else ""), file=str(build_path))

    # distances between all lanes of equal type, both ways
    types = sorted(set(bl.lane_type) | set(rl.lane_type))
    offset_build = np.full(len(bl), np.inf)
    offset_reference = np.full(len(rl), np.inf)
    by_type = {}
    for lane_type in types:
        b_mask, r_mask = bl.lane_type == lane_type, rl.lane_type == lane_type
        b_sub, r_sub = bl.subset(b_mask), rl.subset(r_mask)
        offset_build[b_mask] = r_sub.distance_from(b_sub.x, b_sub.y)
        offset_reference[r_mask] = b_sub.distance_from(r_sub.x, r_sub.y)
        by_type[lane_type] = {
            "length_build_m": round(b_sub.length, 1), "length_reference_m": round(r_sub.length, 1),
            "precision": _share(offset_build[b_mask], b_sub.weight) if len(r_sub) and len(b_sub) else None,
            "recall": _share(offset_reference[r_mask], r_sub.weight) if len(b_sub) and len(r_sub) else None,
        }
    driving_b, driving_r = bl.lane_type == "driving", rl.lane_type == "driving"
    db, dr = offset_build[driving_b], offset_reference[driving_r]
    lanes_b, lanes_r = bl.subset(driving_b), rl.subset(driving_r)
    report["lengths_m"] = {"build": round(lanes_b.length, 1), "reference": round(lanes_r.length, 1)}
    report["precision"] = _share(db, lanes_b.weight)
    report["recall"] = _share(dr, lanes_r.weight)
    report["by_lane_type"] = by_type

    roads_b = build.roads.subset(overlap.contains(build.roads.x, build.roads.y))
    roads_r = reference.roads.subset(overlap.contains(reference.roads.x, reference.roads.y))
    road_b = roads_r.distance_from(roads_b.x, roads_b.y) if len(roads_b) else np.zeros(0)
    road_r = roads_b.distance_from(roads_r.x, roads_r.y) if len(roads_r) else np.zeros(0)
    report["hausdorff_m"] = {
        "lanes": _round(max(db.max(initial=0.0), dr.max(initial=0.0))),
        "roads": _round(max(road_b.max(initial=0.0), road_r.max(initial=0.0))) if len(roads_b) and len(roads_r)
        else None,
    }

    paired_offset = _paired_offsets(lanes_b, lanes_r)
    ok = paired_offset <= PAIR_DISTANCE_M
    values = paired_offset[ok]
    report["offset"] = {
        "mean_m": _round(values.mean()) if len(values) else None,
        "median_m": _round(np.median(values)) if len(values) else None,
        "p95_m": _round(np.percentile(values, 95)) if len(values) else None,
        "paired_fraction": _round(lanes_b.weight[ok].sum() / lanes_b.weight.sum(), 4),
        "pair_distance_m": PAIR_DISTANCE_M,
        "direction_weight_m": DIRECTION_WEIGHT_M,
    }
    fit = fit_similarity(lanes_b, lanes_r)
    report["fitted_transform"] = fit.to_dict() if fit else None

    def junctions_inside(network):
        if not len(network.junctions_xy):
            return 0
        return int(overlap.contains(network.junctions_xy[:, 0], network.junctions_xy[:, 1]).sum())

    report["topology"] = {
        "junctions": {"build": junctions_inside(build), "reference": junctions_inside(reference)},
        "largest_scc_share": {"build": _round(build.largest_scc_share, 4),
                              "reference": _round(reference.largest_scc_share, 4)},
        "dead_end_lanes": {"build": build.dead_ends, "reference": reference.dead_ends},
        "scope": "junctions: inside the overlap; connectivity: whole networks",
    }
    full_offset = np.full(len(build.lanes), np.nan)
    full_offset[np.flatnonzero(b_in)] = offset_build
    return Comparison(report, build, reference, frame, b_in, full_offset, overlap)
