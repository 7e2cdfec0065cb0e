"""Lane borders: the one derivation of every lane's inner and outer border offset t from the flat tables.

A lane's inner border is its inner neighbour's outer border (the lane offset for the lanes next to the centre);
its outer border is the inner one plus its width, or its own border record where it has border records instead
(ASAM OpenDRIVE: width wins when both are present). Sampling, the locator, the lane graph, road marks and the
twin's traffic map all read borders through ``border_offsets``; the per-road path (``LaneSection.outer_borders``)
is checked against it by a property test (tests/test_borders.py).
"""

from __future__ import annotations

import numpy as np


def _outer(arrays, row: np.ndarray, s: np.ndarray, inner: np.ndarray) -> np.ndarray:
    sign = np.sign(arrays.lane_id[row]).astype(float)
    width = arrays.lane_width.evaluate(row, s)
    border = arrays.lane_border.evaluate(row, s)
    return np.where(arrays.lane_uses_border[row], border, inner + sign * width)


def border_offsets(arrays, lane_row: np.ndarray, s: np.ndarray,
                   inner_pair: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(t_inner, t_outer) of lane-table rows at s.

    Without ``inner_pair`` each lane walks out from the centre through its inner neighbours. With it (for every
    pair, the index of the pair of its inner neighbour at the same s, as whole-section sampling has them), each
    lane reuses its neighbour's outer border instead of walking: the same values, computed once per pair.
    """
    lane_row = np.asarray(lane_row, dtype=np.int64)
    s = np.asarray(s, dtype=float)
    rank = arrays.lane_rank[lane_row]
    lane_offset = arrays.section_lane_offset(arrays.lane_section[lane_row], s)
    t_inner = np.empty(len(lane_row))
    t_outer = np.empty(len(lane_row))
    if inner_pair is not None:
        for r in range(int(rank.max(initial=-1)) + 1):
            idx = np.flatnonzero(rank == r)
            t_inner[idx] = lane_offset[idx] if r == 0 else t_outer[inner_pair[idx]]
            t_outer[idx] = _outer(arrays, lane_row[idx], s[idx], t_inner[idx])
        return t_inner, t_outer
    t = lane_offset
    for r in range(int(rank.max(initial=-1)) + 1):
        idx = np.flatnonzero(r <= rank)  # lanes at least r out: step them across their rank-r lane
        row = lane_row[idx] - rank[idx] + r
        last = rank[idx] == r
        t_inner[idx[last]] = t[idx[last]]
        t = t.copy()
        t[idx] = _outer(arrays, row, s[idx], t[idx])
    t_outer[:] = t
    return t_inner, t_outer
