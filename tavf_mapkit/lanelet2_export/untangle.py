"""Lane sections whose borders fold: the samples their bounds keep, so Lanelet2 reads every lanelet right.

``folds.cut_folds`` repairs a border that crosses itself. Some sections stay tangled: lanes further out than
the reference line's radius over a stretch run inside out (netconvert writes wide lane groups through tight
junction turns that way), and their borders run backwards without crossing. In a section with a lanelet that
the loader's orientation test (``orientation``) would turn, the samples of all borders are chosen together
from candidates -- every sample uncut, the samples through which all borders advance
(``folds.monotone_samples``), the corners with one sample between them -- taking the first that leaves no
lanelet of the section turned, else the one that turns fewest, else the cut borders. The chosen samples are
the same for every border of a section, so neighbours still share their bound point for point. What stays
turned gets bounds of its own (``orientation.give_private_bounds``).
"""

from __future__ import annotations

import numpy as np

from tavf_mapkit.lanelet2_export.folds import monotone_samples
from tavf_mapkit.lanelet2_export.nodes import NODE_RADIUS
from tavf_mapkit.lanelet2_export.orientation import _inversions

#: the corners-plus-one-sample candidates are tried on sections with at most this many samples
_MAX_SEARCH = 200


def _bounds(points, keep, start, count, border):
    """The kept points of each border as the file's way will run (with s), points closer than a node to the
    one before dropped as node merging will (the loader's test looks at the point at half the count)."""
    out = []
    for b in border:
        run = slice(start[b], start[b] + count[b])
        line = points[run][keep[run]]
        gap = np.hypot(*np.diff(line[:, :2], axis=0).T) > NODE_RADIUS
        out.append(line[np.concatenate([[True], gap])])
    return out


def untangle_sections(
    arrays,
    borders,
    points: np.ndarray,
    keep: np.ndarray,
    left: np.ndarray,
    right: np.ndarray,
    forward: np.ndarray,
) -> dict[int, np.ndarray]:
    """Choose the samples of tangled sections. ``points``/``keep`` (the cut borders) are updated in place;
    returns {section row: kept samples} for the sections reduced to a sample subset. ``left``/``right``:
    border ids of every lanelet's bounds (in driving direction); ``forward``: whether it drives with s."""
    n_lanes = borders.n_lanes
    section_of_border = np.concatenate([arrays.lane_section, np.arange(len(borders.start) - n_lanes)])
    turned = _turned(points, keep, borders, left, right, forward)
    suspects = np.unique(section_of_border[left[turned]])
    lanelet_section = section_of_border[left]
    # each suspect's sampled borders and lanelets (ascending), by one stable sort rather than a mask per
    # suspect (suspects x borders grows with the square of the map)
    border_runs = _runs_of(np.where(borders.count > 0, section_of_border, -1), suspects)
    lanelet_runs = _runs_of(lanelet_section, suspects)
    turned_in = np.bincount(lanelet_section[turned], minlength=len(section_of_border))
    chosen: dict[int, np.ndarray] = {}
    for section, members, lanelets in zip(suspects.tolist(), border_runs, lanelet_runs):
        m = int(borders.count[members[0]])
        index = borders.start[members][:, None] + np.arange(m)[None, :]
        cut = (points[index], keep[index])
        raw = borders.points[index]
        # the cut borders turn a lanelet here already: try the others, keep the cut ones as the last resort
        candidates = [np.ones(m, dtype=bool), monotone_samples(raw[..., :2], borders.tangent[index[0]])]
        if m <= _MAX_SEARCH:
            for j in range(1, m - 1):
                samples = np.zeros(m, dtype=bool)
                samples[[0, j, m - 1]] = True
                candidates.append(samples)
        best, best_count = None, int(turned_in[section])
        for candidate in candidates:
            points[index], keep[index] = raw, candidate[None, :]
            count = len(_turned(points, keep, borders, left[lanelets], right[lanelets], forward[lanelets]))
            if count < best_count:
                best, best_count = candidate, count
            if count == 0:
                break
        if best is None:
            points[index], keep[index] = cut
        else:
            points[index], keep[index] = raw, best[None, :]
            chosen[int(section)] = best
    return chosen


def _runs_of(key: np.ndarray, wanted: np.ndarray) -> list[np.ndarray]:
    """For each value of ``wanted`` (ascending), the indices i with key[i] == value, ascending."""
    order = np.argsort(key, kind="stable")
    ordered = key[order]
    lo = np.searchsorted(ordered, wanted, side="left")
    hi = np.searchsorted(ordered, wanted, side="right")
    return [order[a:b] for a, b in zip(lo.tolist(), hi.tolist())]


def _turned(points, keep, borders, left, right, forward) -> np.ndarray:
    """Indices (into ``left``) of the lanelets the loader would turn, on points before node merging: the ways
    run with s, so a lanelet against s must have both bounds inverted, one with s neither."""
    if not len(left):
        return np.zeros(0, dtype=np.int64)
    lefts = _bounds(points, keep, borders.start, borders.count, left)
    rights = _bounds(points, keep, borders.start, borders.count, right)
    left_inverted, right_inverted, uncertain = _inversions(lefts, rights)
    against = ~np.asarray(forward, dtype=bool)
    return np.flatnonzero((left_inverted != against) | (right_inverted != against) | uncertain)
