"""The polylines of many steps between lanes at once, as ``drivable._step_polyline`` makes each.

A region has tens of thousands of steps (Maribor: 29,364); one small numpy call per step and lane end is
most of route selection's time. A step whose lanes meet (gap at most ``JOIN_GAP``: no blend, nothing of lane
a cut) is the last ``REACH`` m of a's tail and the first ``REACH`` m of b's head, read here from the lanes'
kept ends (``LaneLines.ends_arrays``) for every step at once. The few others (a blend, or a lane without
kept ends) are left to ``_step_polyline``.
"""

from __future__ import annotations

import numpy as np

from twin.map.lanelines import EndsArrays
from twin.planning.buffer import JOIN_GAP

REACH = 8.0  # m of each lane around a step that is measured (``drivable.REACH``)


def _ranges(start: np.ndarray, stop: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(owner, index): every index of start[k]:stop[k] for each k in order, with its k."""
    counts = stop - start
    owner = np.repeat(np.arange(len(start)), counts)
    index = np.arange(int(counts.sum())) - np.repeat(np.cumsum(counts) - counts, counts) + start[owner]
    return owner, index


def end_headings(ends: EndsArrays) -> tuple[np.ndarray, np.ndarray]:
    """Per lane of ``ends``: the heading of its first and of its last segment (``drivable._end_headings``),
    radians."""
    # (a lane of one point has no segment: its numbers are not used, its indices only kept in range)
    second = np.minimum(ends.head_at[:-1] + 1, max(len(ends.head) - 1, 0))
    before_last = np.maximum(ends.tail_at[1:] - 2, 0)
    first = ends.head[second] - ends.head[ends.head_at[:-1]]
    last = ends.tail[ends.tail_at[1:] - 1] - ends.tail[before_last]
    return np.arctan2(first[:, 1], first[:, 0]), np.arctan2(last[:, 1], last[:, 0])


def joined_steps(ends: EndsArrays, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For steps from lane a[k] to lane b[k] (rows of ``ends``): (joined, owner, points): which steps are
    made here (their lanes meet), and the plan-view points of those steps in step order, each with its step
    k; ``_step_polyline``'s points for each, to the bit."""
    end = ends.tail[ends.tail_at[a + 1] - 1]
    gap = np.hypot(*(ends.head[ends.head_at[b]] - end).T)
    joined = gap <= JOIN_GAP
    k = np.flatnonzero(joined)
    ka, kb = a[k], b[k]
    # the tail of a: its points from REACH m before its end on (the end is a tail point: never empty)
    owner, index = _ranges(ends.tail_at[ka], ends.tail_at[ka + 1])
    length = ends.length[ka][owner]
    along = ends.tail_along[index]
    keep = (along >= length - REACH) & (along <= length + 1e-9)
    tail_owner, tail_index = owner[keep], index[keep]
    # the head of b: its points within REACH m of its entry
    owner, index = _ranges(ends.head_at[kb], ends.head_at[kb + 1])
    keep = ends.head_along[index] <= REACH
    head_owner, head_index = owner[keep], index[keep]
    step = np.concatenate([tail_owner, head_owner])
    order = np.argsort(2 * step + np.r_[np.zeros(len(tail_owner), dtype=np.int64),
                                        np.ones(len(head_owner), dtype=np.int64)], kind="stable")
    points = np.concatenate([ends.tail[tail_index], ends.head[head_index]])[order]
    return joined, k[step[order]], points
