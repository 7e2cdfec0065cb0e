"""planView geometries: line, arc, spiral, poly3, paramPoly3 -- exact, vectorised evaluation.

Every kernel answers the same question for arrays of (geometry, ds): position, heading and curvature.
Kernels work on a GeometryTable (struct of arrays), so one road or a whole network evaluate alike.
Spirals and poly3/paramPoly3 arc lengths are integrated with Gauss-Legendre quadrature on panels small
enough that the result is exact to double precision, rather than with fixed steps.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np


class GeometryKind(IntEnum):
    LINE = 0
    ARC = 1
    SPIRAL = 2
    POLY3 = 3
    PARAM_POLY3 = 4


#: number of parameters stored per geometry kind (the parameter row has 9 slots)
PARAMETER_NAMES = {
    GeometryKind.LINE: (),
    GeometryKind.ARC: ("curvature",),
    GeometryKind.SPIRAL: ("curvStart", "curvEnd"),
    GeometryKind.POLY3: ("a", "b", "c", "d"),
    GeometryKind.PARAM_POLY3: ("aU", "bU", "cU", "dU", "aV", "bV", "cV", "dV", "normalized"),
}
ELEMENT_NAMES = {
    GeometryKind.LINE: "line",
    GeometryKind.ARC: "arc",
    GeometryKind.SPIRAL: "spiral",
    GeometryKind.POLY3: "poly3",
    GeometryKind.PARAM_POLY3: "paramPoly3",
}


@dataclass(frozen=True)
class Geometry:
    """One ``<geometry>`` record of a planView."""

    s: float
    x: float
    y: float
    hdg: float
    length: float
    kind: GeometryKind
    params: tuple[float, ...] = ()
    line: int | None = field(default=None, compare=False)
    extra_xml: tuple[bytes, ...] = field(default=(), compare=False)


#: one numeric row per geometry record: s, x, y, hdg, length, kind, then the 9 parameter slots (zero-padded)
GEOMETRY_COLUMNS = 15
#: the stored row: the first 7 columns of the full one (s, x, y, hdg, length, kind, first parameter). Lines and
#: arcs -- nearly every record of a real map (curves as arcs) -- need no more; a row whose other 8 parameters are
#: not all zero (spiral, poly3, paramPoly3) keeps its 9 parameters in a side table (``ParameterTable``).
#: A city's 5 million rows: 286 MB instead of 612 MB, every value the same float64.
NARROW_COLUMNS = 7
_PARAMETER_COUNT = {kind: len(names) for kind, names in PARAMETER_NAMES.items()}


def split_rows(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(narrow rows, side index, side parameters) of full (n, GEOMETRY_COLUMNS) rows: the first NARROW_COLUMNS
    columns, and the index and 9 parameters of each row of a kind with more parameters than one, or whose
    parameters 2..9 are not all +0.0 (a -0.0 too: its sign is written back)."""
    rows = np.asarray(rows, dtype=float).reshape(-1, GEOMETRY_COLUMNS)
    # every spiral, poly3 and paramPoly3 (as the reader puts them), and any row whose other slots are not +0.0:
    # a slot's bits are all zero exactly when it is +0.0 (-0.0 has its sign bit, NaN its exponent), one test
    # instead of three (a region's repairs split every road's rows). The bits' own ``any`` and a float kind: a
    # road has a few rows, where np.any(... != 0) and comparing with an IntEnum cost 5 times the work
    needs_side = rows[:, NARROW_COLUMNS:].view(np.int64).any(axis=1)
    needs_side |= rows[:, 5] >= _FIRST_SIDE_KIND
    side = np.flatnonzero(needs_side)
    return rows[:, :NARROW_COLUMNS].copy(), side, rows[side, 6:].copy()


#: the first kind with more than one parameter (spiral): its rows always go to the side table
_FIRST_SIDE_KIND = float(GeometryKind.SPIRAL)


def join_rows(narrow: np.ndarray, side_index: np.ndarray, side_params: np.ndarray) -> np.ndarray:
    """The full (n, GEOMETRY_COLUMNS) rows of a narrow table and its side table (``split_rows`` inverted)."""
    rows = np.zeros((len(narrow), GEOMETRY_COLUMNS))
    rows[:, :NARROW_COLUMNS] = narrow
    rows[side_index, 6:] = side_params
    return rows


class ParameterTable:
    """The 9 parameter slots of a table's geometries, read as ``params[rows]`` -> (len(rows), 9): the first slot
    is the narrow table's column (a view), the others are zero except for the rows of the side table (sorted
    row indices and their 9 parameters)."""

    __slots__ = ("first", "side_index", "side_params")

    def __init__(self, first: np.ndarray, side_index: np.ndarray, side_params: np.ndarray):
        self.first = first
        self.side_index = np.asarray(side_index, dtype=np.int64)
        self.side_params = np.asarray(side_params, dtype=float).reshape(-1, 9)

    def __len__(self) -> int:
        return len(self.first)

    @property
    def shape(self) -> tuple[int, int]:
        return len(self.first), 9

    def __getitem__(self, rows) -> np.ndarray:
        rows = np.arange(len(self.first))[rows] if not _is_index_array(rows) else np.asarray(rows, dtype=np.int64)
        scalar = rows.ndim == 0
        rows = np.atleast_1d(rows)
        out = np.zeros((len(rows), 9))
        out[:, 0] = self.first[rows]
        if len(self.side_index) and len(rows):
            at = np.minimum(np.searchsorted(self.side_index, rows), len(self.side_index) - 1)
            hit = self.side_index[at] == rows
            out[hit] = self.side_params[at[hit]]
        return out[0] if scalar else out


def _is_index_array(rows) -> bool:
    return isinstance(rows, np.ndarray) and rows.dtype.kind in "iu"


def geometry_rows(geometries) -> tuple[np.ndarray, np.ndarray, dict | None]:
    """(rows, lines, extra_xml) of Geometry values, the compact form ReferenceLine keeps."""
    n = len(geometries)
    rows = np.zeros((n, GEOMETRY_COLUMNS))
    for k, g in enumerate(geometries):
        rows[k, :6] = (g.s, g.x, g.y, g.hdg, g.length, int(g.kind))
        rows[k, 6:6 + len(g.params)] = g.params[:9]
    lines = np.array([-1 if g.line is None else g.line for g in geometries], dtype=np.int32)
    extra_xml = {k: g.extra_xml for k, g in enumerate(geometries) if g.extra_xml}
    return rows, lines, extra_xml or None


def geometries_from_rows(rows: np.ndarray, lines: np.ndarray, extra_xml: dict | None) -> tuple[Geometry, ...]:
    extra_xml = extra_xml or {}
    out = []
    for k, (row, line) in enumerate(zip(rows.tolist(), lines.tolist())):
        kind = GeometryKind(int(row[5]))
        out.append(Geometry(row[0], row[1], row[2], row[3], row[4], kind, tuple(row[6:6 + _PARAMETER_COUNT[kind]]),
                            None if line < 0 else line, extra_xml.get(k, ())))
    return tuple(out)


@dataclass(frozen=True, eq=False)
class GeometryTable:
    """Geometries as arrays, sorted by (group, s); ``group`` is the road index in a network table."""

    group: np.ndarray
    s: np.ndarray
    x: np.ndarray
    y: np.ndarray
    hdg: np.ndarray
    length: np.ndarray
    kind: np.ndarray
    params: ParameterTable  # params[rows] -> (len(rows), 9)

    @staticmethod
    def from_rows(rows: np.ndarray, group: np.ndarray | None = None, side_index: np.ndarray | None = None,
                  side_params: np.ndarray | None = None) -> "GeometryTable":
        """Columns of (n, NARROW_COLUMNS) rows and their side table (views, no copy), or of full
        (n, GEOMETRY_COLUMNS) rows (split first)."""
        if rows.ndim == 2 and rows.shape[1] == GEOMETRY_COLUMNS:
            rows, side_index, side_params = split_rows(rows)
        n = len(rows)
        return GeometryTable(
            np.zeros(n, dtype=np.int64) if group is None else np.asarray(group, dtype=np.int64),
            rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3], rows[:, 4], rows[:, 5].astype(np.int8),
            ParameterTable(rows[:, 6], np.zeros(0, dtype=np.int64) if side_index is None else side_index,
                           np.zeros((0, 9)) if side_params is None else side_params),
        )

    @staticmethod
    def from_geometries(geometries, group: np.ndarray | None = None) -> "GeometryTable":
        return GeometryTable.from_rows(geometry_rows(geometries)[0], group)

    def __len__(self) -> int:
        return len(self.s)

    def locate(self, group: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(index, found): the geometry that governs each (group, s) -- the group's last one starting at or
        before s; before its first one, that first one (extrapolated back) -- and whether the group has any.

        The one rule by which s picks a geometry: a single road (ReferenceLine) and the whole map
        (NetworkArrays) both evaluate through it. A binary search on s inside each query's group, all queries
        at once, so the search is exact in s (no s / span scaling) and needs no table-sized keys (complex
        group + i*s keys were 16 bytes a row: 78 MB for a city's 5 million arcs). A non-finite s picks what
        those keys picked (group + i*inf is NaN + i*inf, past every key): the table's last row if it is the
        group's, else the group's first."""
        group = np.asarray(group, dtype=np.int64)
        s = np.asarray(s, dtype=float)
        if not len(self.s):
            return np.zeros(len(s), dtype=np.int64), np.zeros(len(s), dtype=bool)
        first = np.searchsorted(self.group, group, side="left")
        finite = np.isfinite(s)
        low = first.copy()
        # invariant: rows [first, low) start at or before s, rows [high, group's end) after it; only the queries
        # still open are carried on (most roads have a few rows, a chain of arcs hundreds)
        open_ = np.flatnonzero(finite)
        high = np.searchsorted(self.group, group[open_], side="right")
        query = s[open_]
        at = low[open_]
        while True:
            done = at >= high
            if done.any():
                low[open_[done]] = at[done]
                keep = ~done
                open_, at, high, query = open_[keep], at[keep], high[keep], query[keep]
            if not len(open_):
                break
            middle = (at + high) >> 1  # at < middle + 1 <= high: inside the group
            before = self.s[middle] <= query
            at = np.where(before, middle + 1, at)
            high = np.where(before, high, middle)
        last = len(self.s) - 1
        index = np.where(low > first, low - 1, np.minimum(first, last))
        index = np.where(finite, index, np.where(self.group[last] == group, last, np.minimum(first, last)))
        return index, self.group[index] == group

    def evaluate(self, index: np.ndarray, ds: np.ndarray):
        """(x, y, heading, curvature) of geometry ``index[i]`` at distance ``ds[i]`` along it."""
        x = np.empty(len(index))
        y = np.empty(len(index))
        hdg = np.empty(len(index))
        curvature = np.empty(len(index))
        kinds = self.kind[index]
        for kind in np.unique(kinds):
            mask = kinds == kind
            g = index[mask]
            kind = GeometryKind(int(kind))
            # lines and arcs read only the first parameter: no (rows, 9) block for a city's millions of arcs
            params = self.params.first[g][:, None] if kind <= GeometryKind.ARC else self.params[g]
            local = _KERNELS[kind](params, self.length[g], ds[mask], g)
            u, v, theta, k = local
            cos_h = np.cos(self.hdg[g])
            sin_h = np.sin(self.hdg[g])
            x[mask] = self.x[g] + cos_h * u - sin_h * v
            y[mask] = self.y[g] + sin_h * u + cos_h * v
            hdg[mask] = self.hdg[g] + theta
            curvature[mask] = k
        return x, y, hdg, curvature


def group_keys(group: np.ndarray, s: np.ndarray) -> np.ndarray:
    """group + i*s of a table's (finite) starts, written in place: ``group + 1j * s`` makes two complex
    temporaries as large (a city's 5 million geometries: 160 MB for a 80 MB table)."""
    keys = np.empty(len(s), dtype=complex)
    keys.real = group
    keys.imag = s
    return keys


# Each local kernel returns (u, v, heading change, curvature) in the geometry's own frame.

def _line(params, length, ds, geometry=None):
    zero = np.zeros_like(ds)
    return ds, zero, zero, zero


def _arc(params, length, ds, geometry=None):
    k = params[:, 0]
    angle = k * ds
    # chord = 2 sin(k ds / 2) / k, written with sinc so that k -> 0 is exact, not 0/0
    chord = ds * np.sinc(angle / (2.0 * np.pi))
    return chord * np.cos(angle / 2.0), chord * np.sin(angle / 2.0), angle, k


_GL_NODES, _GL_WEIGHTS = np.polynomial.legendre.leggauss(16)


def _panel_count(phase_change: np.ndarray) -> np.ndarray:
    """Panels per row so that the integrand's phase changes by at most ~1.5 rad per 16-point panel (exact in
    double). Per row, so that a sample's value never depends on the other samples evaluated with it."""
    return np.clip(np.ceil(np.abs(phase_change) / 1.5), 1, 256).astype(np.int64)


def _integrate(func, upper: np.ndarray, panels: int) -> np.ndarray:
    """Integral of func(t) (vectorised over rows) from 0 to upper[i], composite Gauss-Legendre. The weighted
    sum is numpy's row sum, not a BLAS product: BLAS rounds a row differently by where it sits in the matrix."""
    edges = np.linspace(0.0, 1.0, panels + 1)
    lo, hi = edges[:-1], edges[1:]
    nodes = (0.5 * (hi - lo)[:, None] * (_GL_NODES[None, :] + 1.0) + lo[:, None]).ravel()
    weights = (0.5 * (hi - lo)[:, None] * _GL_WEIGHTS[None, :]).ravel()
    t = upper[:, None] * nodes[None, :]
    return (func(t) * weights).sum(axis=1) * upper


def _spiral(params, length, ds, geometry=None):
    c0 = params[:, 0]
    rate = np.divide(params[:, 1] - params[:, 0], length, out=np.zeros_like(length), where=length > 0)
    theta = c0 * ds + 0.5 * rate * ds * ds
    need = _panel_count(np.abs(c0) * np.abs(ds) + 0.5 * np.abs(rate) * ds * ds)
    u, v = np.empty(len(ds)), np.empty(len(ds))
    for panels in np.unique(need).tolist():
        rows = np.flatnonzero(need == panels)
        c0c, ratec = c0[rows, None], rate[rows, None]
        u[rows] = _integrate(lambda t: np.cos(c0c * t + 0.5 * ratec * t * t), ds[rows], panels)
        v[rows] = _integrate(lambda t: np.sin(c0c * t + 0.5 * ratec * t * t), ds[rows], panels)
    return u, v, theta, c0 + rate * ds


_TABLE_PANELS = 16
_CURVES_PER_BATCH = 4096
_SAMPLES_PER_BATCH = 65536
_LOCAL_NODES, _LOCAL_WEIGHTS = np.polynomial.legendre.leggauss(10)


def _arc_length_table(speed, p_end: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(edges, table): per curve with |c'(p)| = speed(rows, p), 16 panel edges over [0, p_end] and the arc length
    up to each (16-node Gauss-Legendre per panel); ``table[:, -1]`` is the curve's length.

    The edges are uniform, except around a near-cusp (``_dip_edges``): there |c'| is nearly |p - p*| times a
    constant, which one 16-node panel integrates only to ~1e-5 (Andorra road 18894: a 5.73 m curve 0.04 mm off,
    so its @length was "repaired" wrong and its arcs refused)."""
    edges = np.linspace(0.0, 1.0, _TABLE_PANELS + 1)[None, :] * p_end[:, None]  # (curves, panels+1)
    panel_lengths = np.empty((len(p_end), _TABLE_PANELS))
    slowest, fastest, slowest_node = _panel_lengths_into(speed, edges, panel_lengths, with_extremes=True)
    # a curve whose speed falls well below its top somewhere may be a near-cusp; only those are looked at again
    candidates = np.flatnonzero(slowest < _DIP_RATIO * fastest)
    if len(candidates):
        graded = _dip_edges(speed, candidates, p_end[candidates], slowest_node[candidates])
        if graded is not None:
            rows, row_edges = graded
            sub = np.empty((len(rows), _TABLE_PANELS))
            _panel_lengths_into(lambda r, p: speed(rows[r], p), row_edges, sub)
            # where the uniform panels had the length to a nanometre anyway they stay: the curve reads as it did
            off = np.abs(sub.sum(axis=1) - panel_lengths[rows].sum(axis=1)) > _DIP_GAIN
            edges[rows[off]] = row_edges[off]
            panel_lengths[rows[off]] = sub[off]
    return edges, np.concatenate([np.zeros((len(p_end), 1)), np.cumsum(panel_lengths, axis=1)], axis=1)


#: a curve whose slowest table node is slower than this share of its fastest is checked for a near-cusp
_DIP_RATIO = 0.25
#: the closing-in panels replace the uniform ones of a curve only where its length moves by more than this (m)
_DIP_GAIN = 1e-9
_GOLDEN = (np.sqrt(5.0) - 1.0) / 2.0


def _panel_lengths_into(speed, edges: np.ndarray, out: np.ndarray, with_extremes: bool = False):
    """Fill ``out`` (curves, panels) with each panel's arc length (16-node Gauss-Legendre); with_extremes:
    also return per curve the slowest and fastest node speed and where the slowest node lies (its p)."""
    half = 0.5 * (edges[:, 1:] - edges[:, :-1])
    extremes = (np.empty(len(edges)), np.empty(len(edges)), np.empty(len(edges))) if with_extremes else None
    # in batches of curves: 256 nodes per curve and their temporaries would take GBs on a city's curves at once
    # (each row's sum is the same whatever batch it is in)
    for first in range(0, len(edges), _CURVES_PER_BATCH):
        batch = slice(first, first + _CURVES_PER_BATCH)
        nodes = edges[batch, :-1, None] + half[batch, :, None] * (_GL_NODES[None, None, :] + 1.0)
        curves = np.arange(first, first + len(nodes))
        values = speed(curves[:, None, None], nodes)
        out[batch] = (values * _GL_WEIGHTS[None, None, :]).sum(axis=2) * half[batch]
        if extremes is not None:
            flat, flat_nodes = values.reshape(len(nodes), -1), nodes.reshape(len(nodes), -1)
            at = flat.argmin(axis=1)
            extremes[0][batch], extremes[1][batch] = flat[np.arange(len(nodes)), at], flat.max(axis=1)
            extremes[2][batch] = flat_nodes[np.arange(len(nodes)), at]
    return extremes


def _dip_edges(speed, rows: np.ndarray, p_end: np.ndarray, near: np.ndarray):
    """(rows, edges) of the curves among ``rows`` whose speed has a dip narrower than a table panel, with panel
    edges that close in on the dip geometrically from both sides (each panel about twice as far from it as the
    one before: 16 nodes then integrate to double precision), or None when there is no such curve.

    The dip's bottom p* is searched (golden section) between the nodes around the slowest one; its width is
    speed(p*) / |c''(p*)|, |c''| measured from the speed a little beside p* (|c'|^2 ~ speed^2 + |c''|^2 dp^2)."""
    step = p_end / (_TABLE_PANELS * 8)
    lo, hi = np.maximum(near - step, 0.0), np.minimum(near + step, p_end)
    for _ in range(80):  # the bracket shrinks to 0.618^80 of a node spacing: below double precision
        a, b = hi - _GOLDEN * (hi - lo), lo + _GOLDEN * (hi - lo)
        lower = speed(rows, a) <= speed(rows, b)
        lo, hi = np.where(lower, lo, a), np.where(lower, b, hi)
    bottom = 0.5 * (lo + hi)
    slowest = speed(rows, bottom)
    h = step / 8.0
    beside = np.maximum(speed(rows, np.minimum(bottom + h, p_end)), speed(rows, np.maximum(bottom - h, 0.0)))
    bend = np.sqrt(np.maximum(beside * beside - slowest * slowest, 0.0)) / h
    width = np.divide(slowest, bend, out=np.full_like(slowest, np.inf), where=bend > 0)
    sharp = width < p_end / _TABLE_PANELS
    if not sharp.any():
        return None
    rows, p_end, bottom, width = rows[sharp], p_end[sharp], bottom[sharp], np.maximum(width[sharp], 1e-300)
    before, after = bottom, p_end - bottom
    # panels on each side by how many doublings of the dip's width it spans (at least one on a side with length)
    weight_before, weight_after = np.log1p(before / width), np.log1p(after / width)
    n_before = np.rint(_TABLE_PANELS * weight_before / (weight_before + weight_after)).astype(np.int64)
    n_before = np.clip(n_before, (before > 0).astype(np.int64), _TABLE_PANELS - (after > 0).astype(np.int64))
    k = np.arange(_TABLE_PANELS + 1)[None, :]
    nb = n_before[:, None]
    # offsets from the bottom: width * ((1 + side / width) ** (j / n) - 1), j = 0..n, grows to the side's end
    j_before = np.maximum(nb - k, 0)
    j_after = np.maximum(k - nb, 0)
    off_before = width[:, None] * np.expm1(j_before / np.maximum(nb, 1) * np.log1p(before / width)[:, None])
    off_after = width[:, None] * np.expm1(j_after / np.maximum(_TABLE_PANELS - nb, 1)
                                          * np.log1p(after / width)[:, None])
    edges = np.where(k < nb, bottom[:, None] - off_before, bottom[:, None] + off_after)
    edges[:, 0], edges[:, -1] = 0.0, p_end
    edges[np.arange(len(rows)), n_before] = bottom
    return rows, edges


def _arc_length_inverse(speed, p_end: np.ndarray, target: np.ndarray, row: np.ndarray,
                        table: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """p with arc_length(0..p) = target for each sample of a curve with |c'(p)| = speed(rows, p).

    Per curve an arc-length table at 16 panel edges (``_arc_length_table``, or the one given), then per sample
    a few Newton steps from the panel edge with a 10-node rule: exact to ~1e-12 m, ~30 speed evaluations.
    ``row`` maps each sample to its curve (index into p_end).
    """
    edges, table = _arc_length_table(speed, p_end) if table is None else table
    result = np.empty(len(target))
    for first in range(0, len(target), _SAMPLES_PER_BATCH):  # bounded temporaries, as in _arc_length_table
        batch = slice(first, first + _SAMPLES_PER_BATCH)
        r, goal = row[batch], target[batch]
        k = np.clip((table[r, 1:] <= goal[:, None]).sum(axis=1), 0, _TABLE_PANELS - 1)
        a0, a1 = table[r, k], table[r, k + 1]
        p0, p1 = edges[r, k], edges[r, k + 1]
        fraction = np.divide(goal - a0, a1 - a0, out=np.zeros_like(goal), where=a1 > a0)
        p = p0 + fraction * (p1 - p0)
        for _ in range(4):
            h = 0.5 * (p - p0)
            local_nodes = p0[:, None] + h[:, None] * (_LOCAL_NODES[None, :] + 1.0)
            length = a0 + (speed(r[:, None], local_nodes) * _LOCAL_WEIGHTS).sum(axis=1) * h  # no BLAS: _integrate
            p = p - (length - goal) / np.maximum(speed(r, p), 1e-12)
        result[batch] = p
    return result


def _poly3(params, length, ds, geometry=None):
    a, b, c, d = (params[:, i] for i in range(4))
    rows = np.arange(len(ds))

    def slope(r, u):
        return b[r] + u * (2 * c[r] + 3 * d[r] * u)

    # u runs along the local x axis; the curve's arc length is s, so invert it (u_end <= length always)
    u = _arc_length_inverse(lambda r, u: np.sqrt(1.0 + slope(r, u) ** 2), np.maximum(length, 1e-9), ds, rows)
    v = a + u * (b + u * (c + u * d))
    first = slope(rows, u)
    second = 2 * c + 6 * d * u
    curvature = second / (1.0 + first * first) ** 1.5
    return u, v, np.arctan(first), curvature


def _param_poly3(params, length, ds, geometry=None):
    """s is arc length along the curve (the standard's definition; CARLA and libOpenDRIVE read it so too),
    whatever p is: the sample at ds lies at arc length ds from the curve's start. p runs over [0, 1]
    (pRange normalized) or [0, @length] (arcLength); either way the curve ends where p does, and s beyond its
    true length holds that end point. A file whose @length is not that true length therefore leaves a gap
    (@length too short) or a still stretch (too long) at the geometry's end: the validator reports it
    (geometry.param-poly3-length, geometry.gap) and the build repairs it (opendrive/repair_lengths.py)."""
    aU, bU, cU, dU, aV, bV, cV, dV, normalized = (params[:, i] for i in range(9))
    # one table per distinct geometry: samples share the geometry's row
    ids = np.arange(len(ds)) if geometry is None else geometry
    _, first, row = np.unique(ids, return_index=True, return_inverse=True)
    row = row.ravel()
    gu = params[first]
    g_end = np.where(gu[:, 8] > 0.5, 1.0, length[first])

    def speed(r, p):
        du = gu[r, 1] + p * (2 * gu[r, 2] + 3 * gu[r, 3] * p)
        dv = gu[r, 5] + p * (2 * gu[r, 6] + 3 * gu[r, 7] * p)
        return np.hypot(du, dv)

    table = _arc_length_table(speed, g_end)
    total = table[1][:, -1]
    p = _arc_length_inverse(speed, g_end, np.minimum(ds, total[row]), row, table)
    p = np.where(ds < total[row], p, g_end[row])  # at and past the curve's end: exactly its end
    u = aU + p * (bU + p * (cU + p * dU))
    v = aV + p * (bV + p * (cV + p * dV))
    u1 = bU + p * (2 * cU + 3 * dU * p)
    v1 = bV + p * (2 * cV + 3 * dV * p)
    u2 = 2 * cU + 6 * dU * p
    v2 = 2 * cV + 6 * dV * p
    speed_p = np.hypot(u1, v1)
    curvature = np.divide(u1 * v2 - v1 * u2, speed_p ** 3, out=np.zeros_like(speed_p), where=speed_p > 0)
    return u, v, np.arctan2(v1, u1), curvature


def param_poly3_length(params: np.ndarray, p_end: np.ndarray) -> np.ndarray:
    """True arc length of paramPoly3 curves (parameter rows as GeometryTable.params) over p in [0, p_end]."""

    def speed(r, p):
        du = params[r, 1] + p * (2 * params[r, 2] + 3 * params[r, 3] * p)
        dv = params[r, 5] + p * (2 * params[r, 6] + 3 * params[r, 7] * p)
        return np.hypot(du, dv)

    return _arc_length_table(speed, np.asarray(p_end, dtype=float))[1][:, -1]


_KERNELS = {
    GeometryKind.LINE: _line,
    GeometryKind.ARC: _arc,
    GeometryKind.SPIRAL: _spiral,
    GeometryKind.POLY3: _poly3,
    GeometryKind.PARAM_POLY3: _param_poly3,
}
