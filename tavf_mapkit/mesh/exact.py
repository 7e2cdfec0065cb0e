"""numpy helpers whose answer for an element never depends on the other elements computed with it.

The tiled mesher meshes a map in batches and must get the same bits for a road whichever batch it is in, so
sums over many roads at once (one cumsum over every run, a BLAS product, a combined float key) are out.
"""

from __future__ import annotations

import numpy as np


def search_pairs(major: np.ndarray, minor: np.ndarray, q_major: np.ndarray, q_minor: np.ndarray,
                 side: str) -> np.ndarray:
    """``np.searchsorted`` on (major, minor) pairs sorted lexicographically, for query pairs: exact, with no
    combined floating-point key. A complex number is such a pair (numpy orders complex numbers by real, then
    imaginary part; integer majors below 2^53 are exact as reals). Queries are searched in sorted order:
    numpy narrows each search by the one before, 10x faster than in random order."""
    return _search_keys(_pairs(major, minor), q_major, q_minor, side)


def _search_keys(keys: np.ndarray, q_major: np.ndarray, q_minor: np.ndarray, side: str) -> np.ndarray:
    """``search_pairs`` with the keys' pairs made before (``_pairs(major, minor)``)."""
    queries = _pairs(q_major, q_minor)
    if len(queries) < 2:
        return np.searchsorted(keys, queries, side=side)
    step_major, step_minor = np.diff(q_major), np.diff(q_minor)
    if np.all((step_major > 0) | ((step_major == 0) & (step_minor >= 0))):
        return np.searchsorted(keys, queries, side=side)
    order = np.lexsort((q_minor, q_major))
    out = np.empty(len(queries), dtype=np.int64)
    out[order] = np.searchsorted(keys, queries[order], side=side)
    return out


def _pairs(major: np.ndarray, minor: np.ndarray) -> np.ndarray:
    pairs = np.empty(len(major), dtype=complex)
    pairs.real = major
    pairs.imag = minor
    return pairs


def run_cumsum(values: np.ndarray, run: np.ndarray) -> np.ndarray:
    """Cumulative sums restarting at every run (runs are contiguous). Each run's sums are those of the run
    alone, to the bit -- one cumsum over all runs would carry every earlier run's rounding into the next."""
    values = np.asarray(values, dtype=float)
    out = np.empty(len(values))
    if not len(values):
        return out
    starts = np.flatnonzero(np.r_[True, run[1:] != run[:-1]])
    counts = np.diff(np.r_[starts, len(values)])
    bucket = np.ceil(np.log2(counts)).astype(np.int64)  # runs of similar length share a padded table
    for b in np.unique(bucket).tolist():
        rows = np.flatnonzero(bucket == b)
        width = int(counts[rows].max())
        column = np.arange(width)
        valid = column[None, :] < counts[rows][:, None]
        index = starts[rows][:, None] + column[None, :]
        table = np.zeros((len(rows), width))
        table[valid] = values[index[valid]]
        out[index[valid]] = np.cumsum(table, axis=1)[valid]
    return out


def run_interp(x: np.ndarray, run: np.ndarray, xp: np.ndarray, fp: np.ndarray, xp_run: np.ndarray) -> np.ndarray:
    """Linear interpolation of (xp, fp) at x, each x inside the points of its own run (``xp_run``, ascending
    xp within a run); x lies between the run's first and last xp."""
    return RunTable(xp, xp_run).at(run)(x, fp)


class RunTable:
    """Points xp in runs (``xp_run`` ascending, xp ascending within a run), searched many times: the pair keys
    and each run's first and last point are made once (``run_interp`` for several x over the same points, as
    a curvature over several windows asks, costs one search per x, not three)."""

    def __init__(self, xp: np.ndarray, xp_run: np.ndarray):
        self.xp, self.xp_run = xp, xp_run
        self._keys = _pairs(xp_run, xp)

    def at(self, run: np.ndarray) -> _RunQueries:
        """Queries in the given runs (one run per query, the same for every x asked)."""
        first = np.searchsorted(self.xp_run, run, side="left")
        last = np.searchsorted(self.xp_run, run, side="right") - 1
        return _RunQueries(self, run, first, last)


class _RunQueries:
    def __init__(self, table: RunTable, run: np.ndarray, first: np.ndarray, last: np.ndarray):
        self.table, self.run, self.first, self.last = table, run, first, last

    def __call__(self, x: np.ndarray, fp: np.ndarray) -> np.ndarray:
        """``run_interp(x, run, xp, fp, xp_run)``, the same bits."""
        xp, first, last = self.table.xp, self.first, self.last
        found = _search_keys(self.table._keys, self.run, x, "right")
        j = np.clip(found - 1, first, np.maximum(last - 1, first))
        k = np.minimum(j + 1, last)
        dx = xp[k] - xp[j]
        slope = np.divide(fp[k] - fp[j], dx, out=np.zeros(len(x)), where=dx > 0)
        return fp[j] + slope * (x - xp[j])
