"""Explicit centre lines: every lanelet carries our lane centre (relation member role ``centerline``).

Without one, Lanelet2 derives a centre line from the bounds (``calculateCenterline``): walking both bounds it
pairs the next point of one side with the current point of the other, whichever pair is closer, and joins
their midpoints. On straight lanes that is our centre; in curves, where the outer bound's points lie further
apart than the inner one's, it pairs points metres apart in s and strays by decimetres (London: 18 cm on a 6.5
m wide lane of a tight turn), and around folded borders it is meaningless. Our centre costs a quarter more
nodes (London 261,000 -> 322,000) and gives planners on Lanelet2 the centre our lane graph uses, within the
sampling tolerance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tavf_mapkit.lanelet2_export.folds import cut_folds


@dataclass(frozen=True)
class CentreLines:
    points: np.ndarray
    keep: np.ndarray
    start: np.ndarray  # per requested row: its first point
    count: np.ndarray


def centre_lines(sampling, rows: np.ndarray) -> CentreLines:
    """Our centre lines (with lane heights, folds cut) of lane rows (ascending), row by row in s order, on
    every sample: an explicit centre line shares nothing, so it keeps the samples its bounds may have given
    up."""
    chosen = np.isin(sampling.pair_lane, rows)
    points = sampling.center_points()[chosen]
    lane = sampling.pair_lane[chosen]
    heading = sampling.heading[sampling.pair_sample[chosen]]
    points, keep, _ = cut_folds(points, lane, np.column_stack([np.cos(heading), np.sin(heading)]))
    # pairs come lane by lane in row order, as ``rows`` does
    count = np.bincount(lane, minlength=len(sampling.arrays.lane_id))[rows].astype(np.int64)
    return CentreLines(points, keep, np.cumsum(count) - count, count)


def join_centre_lines(parts: list[CentreLines]) -> CentreLines:
    """The centre lines of parts of the map's samples (in map order, rows ascending across them) as one."""
    count = np.concatenate([part.count for part in parts])
    return CentreLines(
        np.concatenate([part.points for part in parts]),
        np.concatenate([part.keep for part in parts]),
        np.cumsum(count) - count,
        count,
    )
