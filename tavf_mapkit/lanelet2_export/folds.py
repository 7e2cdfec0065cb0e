"""Folds of offset curves cut out of lane borders.

A lane border is an offset curve of the reference line. On the inner side of a kink of the reference line, and
where a border lies further out than the curve's radius (the inner edge of a tight U-turn), the offset curve
runs backwards for a while and crosses itself (a swallowtail). The drivable edge is the curve without that
loop. Lanelet2 needs it that way: its loader orients each bound by which side of the other one the other's
middle point lies, and a loop flips that test, so the lanelet would come out half reversed.

A fold shows as a run of segments that run against s (against the reference direction at both ends). Around
each run the part before and the part after are searched for their crossing, and the points between become the
crossing point. Runs are few (kinks and tight turns), so they are handled one by one.
"""

from __future__ import annotations

import numpy as np

#: segments shorter than this (m) have no direction worth testing
_TINY = 1e-6


def backward_segments(
    points: np.ndarray, tangent: np.ndarray, same_way: np.ndarray, min_length: float = _TINY
) -> np.ndarray:
    """Per segment (point k to k+1): does it run against the reference direction? ``same_way[k]``: points k
    and k+1 belong to one way."""
    d = points[1:, :2] - points[:-1, :2]
    m = tangent[1:] + tangent[:-1]
    along = np.einsum("ij,ij->i", d, m)
    return same_way & (along < 0) & (np.hypot(d[:, 0], d[:, 1]) > min_length)


def _crossing(a0, a1, b0, b1):
    """Parameters (u on a, v on b) of the crossing of segment sets a and b (all pairs), NaN where none."""
    r = a1 - a0
    q = b1 - b0
    w = b0[None, :, :] - a0[:, None, :]
    denominator = r[:, None, 0] * q[None, :, 1] - r[:, None, 1] * q[None, :, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = (w[..., 0] * q[None, :, 1] - w[..., 1] * q[None, :, 0]) / denominator
        v = (w[..., 0] * r[:, None, 1] - w[..., 1] * r[:, None, 0]) / denominator
    inside = (u >= 0) & (u <= 1) & (v >= 0) & (v <= 1)
    return np.where(inside, u, np.nan), np.where(inside, v, np.nan)


def cut_folds(
    points: np.ndarray, way: np.ndarray, tangent: np.ndarray, window: int = 64
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(points, keep, folded): the loop of every fold replaced by its crossing point.

    ``way``: the way of every point (points of a way contiguous, in s order); ``tangent``: the reference
    direction (2D unit vector) at every point. ``keep``: points that stay; ``folded``: the ways that had a
    fold cut. Folds that reach a way's end, or whose two sides do not cross within ``window`` segments, stay
    as they are.
    """
    points = points.copy()
    keep = np.ones(len(points), dtype=bool)
    folded = np.zeros(int(way.max(initial=-1)) + 1, dtype=bool)
    if len(points) < 4:
        return points, keep, folded
    same_way = way[1:] == way[:-1]
    backward = backward_segments(points, tangent, same_way)
    if not backward.any():
        return points, keep, folded
    first_of_way = np.searchsorted(way, way, side="left")
    last_of_way = np.searchsorted(way, way, side="right") - 1
    edges = np.diff(np.concatenate([[0], backward.astype(np.int8), [0]]))
    for run_start, run_end in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)):
        # segments run_start .. run_end - 1 run backwards: points run_start .. run_end are in the fold
        lo, hi = first_of_way[run_start], last_of_way[run_start]
        if not keep[run_start : run_end + 1].all():
            continue  # inside a loop an earlier run already cut
        before = np.arange(max(lo, run_start - window), run_start)  # segments (i, i+1) before the run
        after = np.arange(run_end, min(hi, run_end + window))  # segments (j, j+1) after it
        if not len(before) or not len(after):
            continue
        u, _ = _crossing(points[before, :2], points[before + 1, :2], points[after, :2], points[after + 1, :2])
        hits = np.argwhere(np.isfinite(u))
        if not len(hits):
            continue
        # the crossing nearest the fold on both sides: the last segment before it, then the first after it
        order = np.lexsort((hits[:, 1], -hits[:, 0]))
        bi, aj = hits[order[0]]
        i, j = before[bi], after[aj]
        crossing = points[i] + u[bi, aj] * (points[i + 1] - points[i])
        points[i + 1] = crossing
        keep[i + 2 : j + 1] = False
        folded[way[i]] = True
    return points, keep, folded


def monotone_samples(points: np.ndarray, tangent: np.ndarray, min_step: float = 0.0) -> np.ndarray:
    """Which samples of a lane section to keep so that every border runs forward from kept sample to kept
    sample.

    For a section whose borders fold without crossing inside it (lanes further out than the reference line's
    radius over a stretch: inside out, as netconvert writes wide lane groups through tight junction curves) no
    cut can make a border drivable; what Lanelet2 needs is bounds that run forward and stay on their side, so
    the section keeps only the samples where all its borders advance (``points``: (borders, samples, 2);
    ``tangent``: (samples, 2)). The first and last sample always stay: they are the corners the neighbouring
    sections join.
    """
    n = points.shape[1]
    kept = [0]
    for k in range(1, n):
        while True:
            j = kept[-1]
            step = points[:, k] - points[:, j]
            forward = bool(np.all(step @ (tangent[j] + tangent[k]) > min_step))
            if forward or k < n - 1 or len(kept) == 1:
                break
            kept.pop()  # the last sample must stay: give up kept ones it does not advance from
        if forward or k == n - 1:
            kept.append(k)
    keep = np.zeros(n, dtype=bool)
    keep[kept] = True
    return keep
