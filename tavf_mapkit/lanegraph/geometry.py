"""Lane centre lines: lengths and end points of every lane of the map at once, and one lane's polyline."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tavf_mapkit.opendrive.borders import border_offsets
from tavf_mapkit.opendrive.sampling import sample_lanes


@dataclass(frozen=True, eq=False)
class LaneTable:
    """Per row of ``odr.arrays``' lane table (in s direction): centre-line length, first and last point;
    and the centre-line samples themselves (row, s, point), sorted by row then s."""

    length: np.ndarray
    first: np.ndarray  # (n, 3) centre point at the section start
    last: np.ndarray   # (n, 3) centre point at the section end
    sample_row: np.ndarray
    sample_s: np.ndarray
    sample_point: np.ndarray  # (m, 3), no lane height

    @staticmethod
    def build(odr, step: float = 1.0) -> LaneTable:
        arrays = odr.arrays
        n = len(arrays.lane_id)
        sampling = sample_lanes(odr, step, include_end=True)
        centre = sampling.center_points(with_height=False)
        rows = sampling.pair_lane
        segment = np.linalg.norm(np.diff(centre, axis=0), axis=1)
        same_lane = rows[1:] == rows[:-1]
        length = np.bincount(rows[1:][same_lane], weights=segment[same_lane], minlength=n)
        lanes = np.arange(n)
        begin = np.searchsorted(rows, lanes, side="left")
        end = np.searchsorted(rows, lanes, side="right") - 1
        has = end >= begin
        first = np.zeros((n, 3))
        last = np.zeros((n, 3))
        first[has] = centre[begin[has]]
        last[has] = centre[end[has]]
        if not np.all(has):  # zero-length lane sections get no samples: evaluate their single point
            missing = np.flatnonzero(~has)
            s = arrays.section_s0[arrays.lane_section[missing]]
            first[missing] = last[missing] = centre_points(odr, missing, s)
        return LaneTable(length, first, last, rows, sampling.s, centre)


def centre_points(odr, lane_rows: np.ndarray, s: np.ndarray) -> np.ndarray:
    """(n, 3) lane-centre points of lane-table rows at road coordinates s (no lane height)."""
    from tavf_mapkit.opendrive.surface import surface_points

    arrays = odr.arrays
    lane_rows = np.asarray(lane_rows)
    s = np.asarray(s, dtype=float)
    road = arrays.section_road[arrays.lane_section[lane_rows]]
    t_inner, t_outer = border_offsets(arrays, lane_rows, s)
    x, y, z, heading, slope, roll, _ = arrays.reference(road, s)
    return surface_points(x, y, z, heading, slope, roll, 0.5 * (t_inner + t_outer), None)


def section_s_values(s0: float, s1: float, step: float) -> np.ndarray:
    """Evenly spaced s from s0 to s1 inclusive, no further apart than step (at least the two ends)."""
    if s1 - s0 <= 0:
        return np.array([s0])
    count = max(int(np.ceil((s1 - s0) / step - 1e-9)), 1)
    return np.linspace(s0, s1, count + 1)
