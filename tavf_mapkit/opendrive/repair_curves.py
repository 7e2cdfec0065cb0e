"""Curves as arcs: every paramPoly3 and poly3 becomes a chain of arcs (and lines) that every reader evaluates
exactly, so that all of them put a lane border at the same place.

Why: a paramPoly3's s is arc length, and its parameter p is not, so a reader must invert the arc length. This
toolkit does so exactly (opendrive/geometry.py), but libOpenDRIVE (C++) maps s to p through a polyline of the
curve within 1 cm (CubicBezier: chord lengths, the last one stretched to @length) and CARLA evaluates a
paramPoly3 as a polyline too: on netconvert's junction curves their lanes lie millimetres to centimetres from
ours (TAVF build: libOpenDRIVE p99 5.4 mm, up to 4 cm; CARLA p99 4.4 mm), however right the file is. Lines and
arcs have closed forms that every reader evaluates alike.

The repair replaces each curved geometry by a G1 chain of arcs. Knots are placed along the curve where its
curvature changes (a chain of arcs is piecewise-constant curvature: on a piece of length h its heading strays
up to about k' h^2 / 10 from the curve's, which the road's widest lane offset magnifies), and every arc is
exactly as long as the curve between its knots: s stays the curve's arc length at every knot, the pieces sum
to the curve's length, and nothing else along the road moves (lane sections, widths, profiles, objects,
signals keep their s; the road keeps its length). The chain starts at the curve's pose and its heading runs
linearly through each piece, through the curve's heading at the knots shifted so that the error changes sign
on every piece (else it would add up to a drift of position); the smallest change of the inner knot headings
then puts the chain's end on the curve's end (to JOINT, heading exactly). Each arc is checked against the exact
curve at nine points and its start, at the same s: its border deviation -- position error plus widest lane
offset times heading error -- must stay within the tolerance, or the piece is split (by the square root of
its excess) and the curve fitted again. Pieces that turn so little that a line does as well are made lines
(CARLA evaluates an arc through its centre in single precision: a 10 km radius costs it a millimetre), and so is
every piece that curves less than MIN_CURVATURE, along its chord (a heading step of microradians at its ends,
within the same border check); a curve that a single line follows within the tolerance becomes one <line>.

TOLERANCE is 1 mm, the measure of the @length repair ("lane borders stay where they were"): on DLR's TAVF
build it makes 1,399 curves 37,000 arcs (+8 MB of XML, 3 s); 0.1 mm would take 106,000. Either way both
oracles then read the file as we do (they evaluate the same arcs); the tolerance only bounds how far the lanes
moved from netconvert's curves.

A curve that would need more than MAX_PIECES arcs, or whose arcs cannot be fitted (a cusp, an @length longer
than the curve), is kept as it is, and a Repair record says so. (A connecting road with a cusp never gets here:
repair_contacts rebuilds it first.) A road whose geometries are not in s order is
left alone (structure.s-order). A map without paramPoly3 and poly3 is returned unchanged: repairing a repaired
map changes nothing.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from tavf_mapkit.opendrive.geometry import (
    ELEMENT_NAMES,
    GEOMETRY_COLUMNS,
    GeometryKind,
    join_rows,
    split_rows,
)
from tavf_mapkit.opendrive.refline import ReferenceLine, gather_side
from tavf_mapkit.opendrive.repair import Repair
from tavf_mapkit.opendrive.repair_lengths import TOLERANCE as LENGTH_TOLERANCE
from tavf_mapkit.opendrive.repair_redundant import near_line_roads, redundant_lines, repair_redundant
from tavf_mapkit.progress import Progress, Report, no_report, reporter

#: Repair.action of this repair: a curve replaced, and one kept (with why)
CURVE_AS_ARCS = "curve as arcs"
KEPT_CURVE = "curve kept"

#: how far a lane border may move (m): position error + widest lane offset x heading error, at the same s
TOLERANCE = 1e-3
#: a piece ends this close (m) to where the next one begins
JOINT = 1e-8
#: most arcs one curve may become; a curve that needs more is kept (and noted)
MAX_PIECES = 512
CURVES_PER_BATCH = 2000
SECTIONS_PER_BATCH = 2000
#: a curvature whose arc stays this close (m, rad) to its tangent line over its length is written as a line
STRAIGHT = 1e-10
#: a piece that curves less than this (1/m) is a line along its chord, with a heading step of under
#: MIN_CURVATURE x length / 2 at its ends: CARLA evaluates an arc through its centre in single precision,
#: radius x cos(heading) rounded to a float, so an arc of 10 km radius is up to a millimetre off there and one
#: of 10,000 km (the piece at a curve's inflection) half a metre. A line is exact in every reader.
MIN_CURVATURE = 1e-4

#: pieces must fit to this share of the tolerance at the checked points (the deviation is smooth between them)
_MARGIN = 0.9

CURVED = (int(GeometryKind.PARAM_POLY3), int(GeometryKind.POLY3))


def repair_curves(odr, tolerance: float = TOLERANCE, max_pieces: int = MAX_PIECES,
                  progress: Progress | None = None):
    """(map with its paramPoly3 and poly3 as arcs and lines, repairs): one Repair per road whose curves became
    arcs, one per curve kept (and why). ``progress`` hears of the lane sections sampled and curves fitted."""
    from tavf_mapkit.opendrive.network import OpenDriveMap

    table = odr.arrays.geometries
    if not len(table):
        return odr, []
    curved = np.isin(table.kind, CURVED) & (table.length > 0)
    if not curved.any():
        return odr, []
    starts = np.searchsorted(table.group, np.arange(len(odr.roads)), side="left")
    ends = np.searchsorted(table.group, np.arange(len(odr.roads)), side="right")
    ordered = np.ones(len(odr.roads), dtype=bool)
    if len(table) > 1:
        same = table.group[1:] == table.group[:-1]
        ordered[table.group[1:][same & (np.diff(table.s) < 0)]] = False
    rows = np.flatnonzero(curved & ordered[table.group])
    if not len(rows):
        return odr, []
    # the part of each curve the road uses: up to the next geometry's start (a shadowed tail is never read)
    next_row = np.minimum(rows + 1, len(table) - 1)
    following = np.where(rows + 1 < ends[table.group[rows]], table.s[next_row], np.inf)
    used = np.minimum(table.length[rows], following - table.s[rows])
    widest = _widest_offsets(odr, np.unique(table.group[rows]), report=reporter(progress, "lane sections"))
    widest = widest[table.group[rows]]
    # in batches of curves: memory bounded by the batch, not the map (Maribor: 6 GB in one go). The roads whose
    # last curve is fitted get their new reference lines at once, as views of one new table of rows (no
    # per-road assembly: a region's 59,000 roads spent more in it than in fitting); Columbus's 466,000 curves
    # as chains at once, and their 5.1 million pieces as Geometry records, took GBs. Every road's line is
    # given rows of such a table, in road order, those without curves too: theirs are views of the table of the
    # map given (odr.arrays), which would otherwise stay alive with them after that map is gone
    roads, repairs = list(odr.roads), []
    done = 0  # roads[:done] hold their new rows
    pending = _PendingCurves()  # fitted curves of the roads not done yet
    maybe_redundant = False
    near_lines = np.zeros(len(roads), dtype=bool)  # per road: two consecutive lines of near headings
    report = reporter(progress, "curves")
    for first in range(0, len(rows), CURVES_PER_BATCH):
        report(first, len(rows))
        batch = slice(first, first + CURVES_PER_BATCH)
        pending.add(rows[batch], fit_curves(table, rows[batch], used[batch], widest[batch], tolerance, max_pieces),
                    table.s[rows[batch]])
        # the road of the next batch's first curve may have curves in this batch too: it waits for them
        upto = int(table.group[rows[first + CURVES_PER_BATCH]]) if first + CURVES_PER_BATCH < len(rows) \
            else len(roads)
        made, redundant, near_lines[done:upto] = _replace_curves(roads, done, upto, int(starts[done]) if done < len(roads) else len(table),
                                          pending.take(int(starts[upto]) if upto < len(roads) else len(table)),
                                          tolerance, check_redundant=not maybe_redundant)
        repairs += made
        maybe_redundant = maybe_redundant or redundant
        done = upto
    report(len(rows), len(rows))
    if not any(r.action == CURVE_AS_ARCS for r in repairs):
        return odr, repairs
    repaired = OpenDriveMap(odr.header, tuple(roads), odr.junctions, odr.controllers, odr.source, odr.warnings,
                            odr.extra_xml)
    # the given map's tables are done with (every road's rows are in new tables now) and made again if that map is
    # asked for them: not held beside the repaired map's while the caller still holds the given one (Columbus:
    # 150 MB)
    del table
    odr.__dict__.pop("arrays", None)
    if maybe_redundant:
        # a curve that became a line beside a line of its heading is one line with it (ASAM: redundant lines)
        repaired, merged = repair_redundant(repaired, near_lines)
        repairs += merged
    return repaired, repairs


class _PendingCurves:
    """The fitted curves (``FittedCurves`` of consecutive batches) whose roads have not had their new lines yet:
    per curve its table row, why it was kept (or None) and its chain's planView rows; in table-row order."""

    def __init__(self):
        self.rows, self.kept, self.piece_count, self.pieces = np.zeros(0, dtype=np.int64), [], \
            np.zeros(0, dtype=np.int64), np.zeros((0, GEOMETRY_COLUMNS))

    def add(self, rows: np.ndarray, fitted: FittedCurves, s: np.ndarray) -> None:
        self.rows = np.concatenate([self.rows, rows])
        self.kept += fitted.kept
        self.piece_count = np.concatenate([self.piece_count, np.diff(fitted.first_piece)])
        self.pieces = np.concatenate([self.pieces, fitted.rows(s)])

    def take(self, before_row: int) -> tuple[np.ndarray, list, np.ndarray, np.ndarray]:
        """(table rows, kept, piece counts, pieces) of the curves on table rows before ``before_row``, which
        leave the pending ones."""
        n = int(np.searchsorted(self.rows, before_row))
        m = int(self.piece_count[:n].sum())
        taken = self.rows[:n], self.kept[:n], self.piece_count[:n], self.pieces[:m]
        self.rows, self.kept, self.piece_count, self.pieces = \
            self.rows[n:], self.kept[n:], self.piece_count[n:], self.pieces[m:]
        return taken


def _replace_curves(roads: list, lo: int, hi: int, first_row: int, fitted, tolerance: float,
                    check_redundant: bool) -> tuple[list, bool, np.ndarray]:
    """Give roads[lo:hi] (whose planView rows start at ``first_row`` of the map's table) their fitted curves as
    chains of rows, in place: one new table of rows for all of them, each road's line a view of its part (a road
    without a replaced curve keeps its line, on the new rows). ``fitted``: ``_PendingCurves.take``. Returns (the
    repairs, in road order: per road one per curve kept and one for its curves replaced; whether a replaced road
    now has redundant lines, asked only when ``check_redundant``; per road whether its line has two consecutive
    lines of near headings, ``near_line_roads``)."""
    curve_rows, kept, piece_count, pieces = fitted
    lines_of = [road.reference_line for road in roads[lo:hi]]
    counts = np.array([len(line) for line in lines_of], dtype=np.int64)
    old_bounds = np.concatenate([[0], np.cumsum(counts)])
    if not old_bounds[-1]:
        return [], False, np.zeros(hi - lo, dtype=bool)
    side_index, side_params = gather_side(lines_of, counts)
    old = join_rows(np.concatenate([line.narrow for line in lines_of if len(line)]), side_index, side_params)
    old_lines = np.concatenate([line.lines for line in lines_of if len(line)]).astype(np.int32, copy=False)
    position = curve_rows - first_row  # each curve's row in ``old``
    chained = piece_count > 0
    replaced = position[chained]
    # each record becomes one row, a replaced curve its chain's; record i's first row is then at new_start[i]
    block_length = np.ones(len(old), dtype=np.int64)
    block_length[replaced] = piece_count[chained]
    new_start = np.concatenate([[0], np.cumsum(block_length)])
    new = np.empty((int(new_start[-1]), GEOMETRY_COLUMNS))
    taken_over = np.ones(len(old), dtype=bool)
    taken_over[replaced] = False
    new[new_start[:-1][taken_over]] = old[taken_over]
    chain_count = piece_count[chained]
    within = np.arange(len(pieces)) - np.repeat(np.cumsum(chain_count) - chain_count, chain_count)
    new[np.repeat(new_start[replaced], chain_count) + within] = pieces
    new_lines = np.repeat(old_lines, block_length)
    narrow, new_side_index, new_side_params = split_rows(new)
    new_bounds = new_start[old_bounds]
    side_bounds = np.searchsorted(new_side_index, new_bounds)
    # per road: curves replaced, their kinds, arcs among its new rows and lines it gained (the repair's numbers)
    n_roads = hi - lo
    old_road = np.repeat(np.arange(n_roads), counts)
    new_road = np.repeat(np.arange(n_roads), np.diff(new_bounds))
    replaced_road = old_road[replaced]
    replaced_count = np.bincount(replaced_road, minlength=n_roads)
    kinds = old[replaced, 5]
    param_poly3 = np.bincount(replaced_road, weights=kinds == int(GeometryKind.PARAM_POLY3), minlength=n_roads)
    poly3 = np.bincount(replaced_road, weights=kinds == int(GeometryKind.POLY3), minlength=n_roads)
    arcs = np.bincount(new_road, weights=new[:, 5] == int(GeometryKind.ARC), minlength=n_roads)
    more_lines = np.bincount(new_road, weights=new[:, 5] == int(GeometryKind.LINE), minlength=n_roads) - \
        np.bincount(old_road, weights=old[:, 5] == int(GeometryKind.LINE), minlength=n_roads)
    first_replaced = np.full(n_roads, -1, dtype=np.int64)
    first_replaced[replaced_road[::-1]] = replaced[::-1]  # the last write per road wins: its first curve
    kept_at: dict = {}  # road -> [(source line, what was kept and why)]
    for k in np.flatnonzero(~chained).tolist():
        row = int(position[k])
        kept_at.setdefault(int(old_road[row]), []).append((
            None if old_lines[row] < 0 else int(old_lines[row]),
            f"{ELEMENT_NAMES[GeometryKind(int(old[row, 5]))]} at s={float(old[row, 0]):.6g} kept: {kept[k]}"))
    with_curves = np.zeros(n_roads, dtype=bool)
    with_curves[old_road[position]] = True
    near_lines = near_line_roads(new, new_road, n_roads)
    asked = near_lines & with_curves if check_redundant else None
    del old, new  # the full rows go before the roads' new lines are made
    repairs, redundant = [], False
    for r in range(n_roads):
        a, b = int(new_bounds[r]), int(new_bounds[r + 1])
        road, line = roads[lo + r], lines_of[r]
        for source, detail in kept_at.get(r, ()):
            repairs.append(Repair(KEPT_CURVE, road.id, source, detail))
        if not replaced_count[r]:
            if b > a:
                line.share_rows(narrow[a:b])
        else:
            sa, sb = int(side_bounds[r]), int(side_bounds[r + 1])
            extra_xml = None
            if line.extra_xml:  # a replaced curve's unknown children go with its first piece
                base = int(old_bounds[r])
                extra_xml = {int(new_start[base + i] - a): line.extra_xml[i] for i in sorted(line.extra_xml)
                             if line.extra_xml[i]}
            line = ReferenceLine.from_narrow(narrow[a:b], new_side_index[sa:sb] - a, new_side_params[sa:sb],
                                             new_lines[a:b], extra_xml)
            roads[lo + r] = replace(road, reference_line=line)
            names = " and ".join(name for name, count in (("paramPoly3", param_poly3[r]), ("poly3", poly3[r]))
                                 if count)
            source = int(old_lines[first_replaced[r]])
            repairs.append(Repair(CURVE_AS_ARCS, road.id, None if source < 0 else source,
                                  f"{int(replaced_count[r])} {names} as {int(arcs[r])} arcs and "
                                  f"{int(more_lines[r]):+d} lines (lane borders within {tolerance * 1000:g} mm of "
                                  f"the curve's)"))
        if asked is not None and asked[r] and not redundant:
            redundant = bool(redundant_lines(line.geometries))
    return repairs, redundant, near_lines


def _widest_offsets(odr, road_indices: np.ndarray, step: float = 1.0, report: Report = no_report) -> np.ndarray:
    """Per road of the map, the largest |t| of any lane border of the road if it is one of ``road_indices``
    (sampled every ``step`` m and at section ends; else 0): how far from the reference line a heading error is
    felt."""
    from tavf_mapkit.opendrive.sampling import section_samples

    arrays = odr.arrays
    all_sections = np.flatnonzero(np.isin(arrays.section_road, road_indices))
    widest = np.zeros(len(odr.roads))
    if not len(all_sections):
        return widest
    for first in range(0, len(all_sections), SECTIONS_PER_BATCH):  # whole-map samples would not fit in memory
        report(first, len(all_sections))
        sections = all_sections[first:first + SECTIONS_PER_BATCH]
        sample_section, sample_s = section_samples(arrays, step, True, sections)
        lane_offset, pair_road, t_outer = _lateral_offsets(arrays, sample_section, sample_s)
        np.maximum.at(widest, arrays.section_road[sample_section], np.abs(lane_offset))
        if len(pair_road):
            np.maximum.at(widest, pair_road, np.abs(t_outer))
    report(len(all_sections), len(all_sections))
    return widest


def _lateral_offsets(arrays, sample_section: np.ndarray, sample_s: np.ndarray):
    """(lane offset at each sample, road and outer border offset of each lane's sample): the numbers of
    ``sampling.sample_lanes_at`` (its pairs, its ``border_offsets``, its sample budget) that the widest offset
    needs, without the reference line's pose at every sample, which it does not (half of the sampling's time)."""
    from tavf_mapkit.opendrive.borders import border_offsets
    from tavf_mapkit.opendrive.sampling import lane_pairs

    sample_section, sample_s = np.asarray(sample_section, dtype=np.int64), np.asarray(sample_s, dtype=float)
    lane_offset = arrays.section_lane_offset(sample_section, sample_s)
    pair_lane, pair_sample, inner_pair = lane_pairs(arrays, sample_section)
    _, t_outer = border_offsets(arrays, pair_lane, sample_s[pair_sample], inner_pair)
    return lane_offset, arrays.section_road[arrays.lane_section[pair_lane]], t_outer


@dataclass(frozen=True)
class FittedCurves:
    """What ``fit_curves`` made of each curve: the pieces of its chain of arcs, in its own s (from 0) -- start
    offset, pose and curvature of each, flat arrays in curve and s order, curve k's from ``first_piece[k]`` to
    ``first_piece[k + 1]`` -- or, for a curve kept (no pieces), why (``kept[k]``; None for a curve fitted)."""

    kept: list
    first_piece: np.ndarray
    ds: np.ndarray
    x: np.ndarray
    y: np.ndarray
    hdg: np.ndarray
    curvature: np.ndarray
    length: np.ndarray

    def rows(self, s: np.ndarray) -> np.ndarray:
        """The planView rows (GEOMETRY_COLUMNS) of every piece, each curve's at its s in the road (``s``): a piece
        that turns less than STRAIGHT over its length is a line, the others arcs."""
        k, length = self.curvature, self.length
        straight = (np.abs(k) * length <= STRAIGHT) & (0.5 * np.abs(k) * length * length <= STRAIGHT)
        rows = np.zeros((len(k), GEOMETRY_COLUMNS))
        rows[:, 0] = np.repeat(s, np.diff(self.first_piece)) + self.ds
        rows[:, 1], rows[:, 2], rows[:, 3], rows[:, 4] = self.x, self.y, self.hdg, length
        rows[:, 5] = np.where(straight, int(GeometryKind.LINE), int(GeometryKind.ARC))
        rows[:, 6] = np.where(straight, 0.0, k)
        return rows


def _wrap(angle):
    return (angle + np.pi) % (2.0 * np.pi) - np.pi


def _chord(a, b):
    """Displacement per unit length of an arc whose heading turns from a to b: e^{i(a+b)/2} sinc((b-a)/2),
    exact as the turn goes to 0."""
    return np.exp(0.5j * (a + b)) * np.sinc((b - a) / (2.0 * np.pi))


_GL_NODES, _GL_WEIGHTS = np.polynomial.legendre.leggauss(16)
_GL4_NODES, _GL4_HALF_WEIGHTS = np.polynomial.legendre.leggauss(4)
_GL4, _GL4_WEIGHTS = 0.5 * (_GL4_NODES + 1.0), 0.5 * _GL4_HALF_WEIGHTS  # on [0, 1]
#: panels of each curve's arc-length table (16-point Gauss-Legendre each: exact to double precision)
_GRID = 64


@dataclass(frozen=True, eq=False)
class Curves:
    """Cubic curves (u(p), v(p)) in their geometries' frames, over p in [0, p_end], with arc-length tables.

    The fit works in p, where a paramPoly3 or poly3 is a polynomial: arc length is integrated forward from
    the table (s(p) = table + one Gauss-Legendre panel), never inverted, which is what makes evaluating a
    paramPoly3 at s expensive."""

    u: np.ndarray  # (n, 4): a, b, c, d
    v: np.ndarray
    x: np.ndarray
    y: np.ndarray
    hdg: np.ndarray
    p_end: np.ndarray
    table: np.ndarray  # (n, _GRID + 1): arc length at p_end * k / _GRID
    overrun: np.ndarray | None = None  # how much longer than the curve its used part is (< LENGTH_TOLERANCE)

    @staticmethod
    def of(table, rows: np.ndarray, used: np.ndarray) -> tuple[Curves, np.ndarray]:
        """The used part of each curve, and per curve whether it is shorter than its used length by more than
        the @length repair leaves (a reader would stand still at its end: no chain of arcs does that). Up to
        that, the chain runs on along the end's tangent (``overrun``), where the next geometry starts."""
        params = table.params[rows]
        poly3 = table.kind[rows] == int(GeometryKind.POLY3)
        unit = np.tile([0.0, 1.0, 0.0, 0.0], (len(rows), 1))
        u = np.where(poly3[:, None], unit, params[:, 0:4])
        v = np.where(poly3[:, None], params[:, 0:4], params[:, 4:8])
        p_max = np.where(~poly3 & (params[:, 8] > 0.5), 1.0, table.length[rows])
        whole = Curves(u, v, table.x[rows], table.y[rows], table.hdg[rows], p_max, np.zeros((len(rows), 1)))
        whole = replace(whole, table=whole._arc_length_table(np.arange(len(rows))))
        total = whole.table[:, -1]
        short = used > total + LENGTH_TOLERANCE
        # only a curve whose used part ends before its end gets another p_end and table (each curve's numbers
        # are its own, whichever curves are computed with it); most are used to their end
        cut = np.flatnonzero(used < total)
        p_end, arc_table = p_max.copy(), whole.table.copy()
        if len(cut):
            p_end[cut] = whole.p_at(cut, used[cut])
            arc_table[cut] = replace(whole, p_end=p_end)._arc_length_table(cut)
        return replace(whole, p_end=p_end, table=arc_table, overrun=np.maximum(used - total, 0.0)), short

    def _arc_length_table(self, curves: np.ndarray) -> np.ndarray:
        """(len(curves), _GRID + 1): arc length at p_end * k / _GRID of each of the ``curves``."""
        edges = self.p_end[curves][:, None] * np.linspace(0.0, 1.0, _GRID + 1)[None, :]
        half = 0.5 * np.diff(edges, axis=1)
        nodes = edges[:, :-1, None] + half[:, :, None] * (_GL_NODES + 1.0)
        panels = (self.speed(curves[:, None, None], nodes) * _GL_WEIGHTS).sum(axis=2) * half
        return np.concatenate([np.zeros((len(curves), 1)), np.cumsum(panels, axis=1)], axis=1)

    def tangent(self, c, p):
        """(du/dp, dv/dp) at p."""
        return _tangent_component(self.u, c, p), _tangent_component(self.v, c, p)

    def derivatives(self, c, p):
        """First, second and third derivatives of u and v by p: (du, dv, ddu, ddv, dddu, dddv)."""
        u, v = self.u[c], self.v[c]
        return (*self.tangent(c, p), 2 * u[..., 2] + 6 * u[..., 3] * p, 2 * v[..., 2] + 6 * v[..., 3] * p,
                6 * u[..., 3], 6 * v[..., 3])

    def speed(self, c, p):
        du, dv = self.tangent(c, p)
        if isinstance(du, np.ndarray) and du.ndim and du.shape == np.shape(dv):
            return np.hypot(du, dv, out=du)  # into du, made for this: no third array of millions
        return np.hypot(du, dv)

    def pose(self, c, p):
        """(x, y, heading) of curve c at p, in the map's frame."""
        u, v = self.u[c], self.v[c]
        lu = u[..., 0] + p * (u[..., 1] + p * (u[..., 2] + p * u[..., 3]))
        lv = v[..., 0] + p * (v[..., 1] + p * (v[..., 2] + p * v[..., 3]))
        du, dv = self.tangent(c, p)
        cos, sin = np.cos(self.hdg[c]), np.sin(self.hdg[c])
        return (self.x[c] + cos * lu - sin * lv, self.y[c] + sin * lu + cos * lv,
                self.hdg[c] + np.arctan2(dv, du))

    def curvature_rate(self, c, p):
        """(curvature, its derivative along s) at p."""
        du, dv, ddu, ddv, dddu, dddv = self.derivatives(c, p)
        square = du * du + dv * dv
        cross = du * ddv - dv * ddu
        with np.errstate(all="ignore"):
            curvature = cross / square ** 1.5
            rate = ((du * dddv - dv * dddu) / square ** 1.5
                    - 3.0 * cross * (du * ddu + dv * ddv) / square ** 2.5) / np.sqrt(square)
        return curvature, rate

    def arc_length(self, c, p):
        """s at p: the table up to p's panel, one Gauss-Legendre panel from there."""
        k = np.clip(np.floor(p / self.p_end[c] * _GRID), 0, _GRID - 1).astype(np.int64)
        start = self.p_end[c] * k / _GRID
        half = 0.5 * (p - start)
        nodes = start[..., None] + half[..., None] * (_GL_NODES + 1.0)
        return self.table[c, k] + (self.speed(c[..., None], nodes) * _GL_WEIGHTS).sum(axis=-1) * half

    def arc_length_along(self, c, pa, pb, fractions):
        """Arc length from p_a to p_a + (p_b - p_a) f for increasing fractions f, per row of (c, p_a, p_b):
        4-point Gauss-Legendre between consecutive fractions (a piece is short, its speed smooth)."""
        edges = np.r_[0.0, fractions]
        width = np.diff(edges)
        x = edges[:-1, None] + width[:, None] * _GL4[None, :]
        p = pa[:, None, None] + (pb - pa)[:, None, None] * x[None, :, :]
        gaps = (self.speed(c[:, None, None], p) * (width[:, None] * _GL4_WEIGHTS)).sum(axis=2)
        return np.cumsum(gaps, axis=1) * (pb - pa)[:, None]

    def p_at(self, c, s):
        """p where the arc length is s (Newton from the table)."""
        k = np.clip((self.table[c, 1:] <= s[:, None]).sum(axis=1), 0, _GRID - 1)
        p0 = self.p_end[c] * k / _GRID
        p1 = self.p_end[c] * (k + 1) / _GRID
        a0, a1 = self.table[c, k], self.table[c, k + 1]
        p = p0 + np.divide(s - a0, a1 - a0, out=np.zeros_like(s), where=a1 > a0) * (p1 - p0)
        for _ in range(6):
            p = p - (self.arc_length(c, p) - s) / np.maximum(self.speed(c, p), 1e-12)
        return p


def _tangent_component(coefficients: np.ndarray, c, p):
    """b + p (2 c + 3 d p) of the cubics ``coefficients[c]`` (rows a, b, c, d) at p, in one array the size of
    the result: the fit asks it of millions of points, and a temporary per operation is most of its time. The
    same operations on the same operands as the formula's, only in place: the same bits."""
    b, c2, d = (coefficients[:, k][c] for k in (1, 2, 3))
    result = 3 * d * p
    if not isinstance(result, np.ndarray) or result.shape != np.broadcast_shapes(np.shape(result), np.shape(c2)):
        return b + p * (2 * c2 + result)
    result += 2 * c2
    result *= p
    result += b
    return result


def fit_curves(table, rows: np.ndarray, used: np.ndarray, lever: np.ndarray, tolerance: float,
               max_pieces: int = MAX_PIECES) -> FittedCurves:
    """Per curve (``rows`` of a GeometryTable, over its first ``used`` metres; ``lever``: the road's widest
    lane offset), a chain of arcs whose lane borders lie within ``tolerance`` of the curve's, or why there is none.

    All curves at once: pieces are flat arrays (curve, p_a, p_b) in curve and s order; each round fits every
    unfinished curve, accepts those whose pieces all fit, and splits the pieces that do not."""
    n = len(rows)
    outcome: list = [None] * n
    budget = tolerance * _MARGIN
    curves, short = Curves.of(table, rows, used)
    for k in np.flatnonzero(short).tolist():
        outcome[k] = (f"@length {table.length[rows[k]]:.9g} m is longer than the curve "
                      f"({curves.table[k, -1]:.9g} m)")
    straight = _straight(curves, lever, budget) & ~short
    # chains accepted, as blocks of (curve, ds, x, y, heading, curvature, length) of their pieces
    accepted = []
    lines = np.flatnonzero(straight)
    if len(lines):
        x, y, hdg = curves.pose(lines, np.zeros(len(lines)))
        accepted.append((lines, np.zeros(len(lines)), x, y, hdg, np.zeros(len(lines)), used[lines].copy()))
        for k in lines.tolist():
            outcome[k] = _FITTED
    todo = np.flatnonzero(~straight & ~short)
    _refine(curves, *_initial_pieces(curves, todo, lever[todo], budget, max_pieces), used, lever, budget,
            max_pieces, tolerance, outcome, accepted, split_neighbours=False)
    # a piece next to a line can be stuck: the line fixes the heading at their knot, so the piece bends harder
    # the more it is split (Baltimore 41883). Only the curves that failed are fitted again, splitting such
    # neighbours too, so that every curve that fitted keeps its arcs
    failed = np.array([k for k in todo.tolist() if outcome[k] is None], dtype=np.int64)
    if len(failed):
        _refine(curves, *_initial_pieces(curves, failed, lever[failed], budget, max_pieces), used, lever, budget,
                max_pieces, tolerance, outcome, accepted, split_neighbours=True)
    for k in failed.tolist():
        if outcome[k] is None:
            outcome[k] = f"its arcs do not fit within {tolerance * 1000:g} mm after {_MAX_ROUNDS} refinements"
    # each curve's pieces are one run of one block: a stable sort by curve puts them in curve and s order
    blocks = [np.concatenate(column) for column in zip(*accepted)] if accepted else [np.zeros(0)] * 7
    curve = blocks[0].astype(np.int64)
    order = np.argsort(curve, kind="stable")
    first_piece = np.concatenate([[0], np.cumsum(np.bincount(curve, minlength=n))])
    return FittedCurves([None if why is _FITTED else why for why in outcome], first_piece,
                        *(column[order] for column in blocks[1:]))


#: fit_curves' outcome of a curve whose chain was accepted
_FITTED = object()


def _refine(curves, curve, pa, pb, used, lever, budget, max_pieces, tolerance, outcome, accepted,
            split_neighbours: bool) -> None:
    """Fit every curve's pieces (flat arrays, in curve and s order) round by round; a curve whose pieces all fit
    is _FITTED in ``outcome`` and its pieces a block of ``accepted`` (see fit_curves), one that needs too many
    pieces gets the reason; the rest stay None."""
    n = len(outcome)
    why = f"more than {max_pieces} arcs would be needed to stay within {tolerance * 1000:g} mm"
    for _ in range(_MAX_ROUNDS):
        count = np.bincount(curve, minlength=n)
        over = count > max_pieces
        for k in np.flatnonzero(over).tolist():
            outcome[k] = why
        keep = ~over[curve]
        curve, pa, pb = curve[keep], pa[keep], pb[keep]
        if not len(curve):
            break
        chain, deviation, closed = _arc_chains(curves, curve, pa, pb, used, lever, budget)
        fits = closed & (np.bincount(curve, weights=deviation > budget, minlength=n) == 0)
        done = fits[curve]
        if done.any():
            accepted.append((curve[done], *(value[done] for value in chain)))
            for k in np.flatnonzero(fits).tolist():
                outcome[k] = _FITTED
        # what does not fit is split: a piece by the square root of its excess (its heading error grows with
        # the square of its length), every piece of a curve that fits but does not close in two
        ratio = np.nan_to_num(deviation / budget, nan=4.0, posinf=4.0)
        parts = np.where(ratio > 1.0, np.clip(np.ceil(np.sqrt(ratio) * 1.1), 2, 8), 1).astype(np.int64)
        parts = np.where(~closed[curve] & (parts == 1), 2, parts)
        if split_neighbours:  # the pieces on either side of one that does not fit are halved too
            bad = ratio > 1.0
            same = curve[1:] == curve[:-1]
            beside = np.r_[bad[1:] & same, False] | np.r_[False, bad[:-1] & same]
            parts = np.where(beside & (parts == 1), 2, parts)
        curve, pa, pb, parts = curve[~done], pa[~done], pb[~done], parts[~done]
        step = np.repeat((pb - pa) / parts, parts)
        k = np.arange(parts.sum()) - np.repeat(np.cumsum(parts) - parts, parts)
        start = np.repeat(pa, parts) + k * step
        end = np.where(k == np.repeat(parts, parts) - 1, np.repeat(pb, parts), start + step)
        curve, pa, pb = np.repeat(curve, parts), start, end


def _s_of(curves, curve, p, used):
    """s at p, exactly 0 at the start and ``used`` at the end (so that the pieces sum to the used length)."""
    s = curves.arc_length(curve, p)
    s = np.where(p <= 0.0, 0.0, s)
    return np.where(p >= curves.p_end[curve], used[curve], s)


def _straight(curves, lever, budget) -> np.ndarray:
    """Which curves a single line from their start (over their used length) follows within ``budget``."""
    n = len(curves.p_end)
    c = np.arange(n)[:, None]
    p = curves.p_end[:, None] * np.linspace(0.0, 1.0, _GRID + 1)[None, :]
    x, y, hdg = curves.pose(c, p)
    s = curves.table
    line_x = x[:, :1] + s * np.cos(hdg[:, :1])
    line_y = y[:, :1] + s * np.sin(hdg[:, :1])
    deviation = np.hypot(x - line_x, y - line_y) + lever[:, None] * np.abs(_wrap(hdg - hdg[:, :1]))
    return deviation.max(axis=1) <= budget


def _initial_pieces(curves, todo, lever, budget, max_pieces: int):
    """(curve, p_a, p_b) of a first split of each curve: as many pieces as its curvature's rate asks for (a
    chain of arcs over a curvature that changes at rate k' turns up to ~k' h^2 / _HEADING_SPREAD away from
    the curve on pieces of length h, which the widest lane magnifies), spread where the rate is, and at most
    _MAX_TURN of turn each."""
    if not len(todo):
        empty = np.zeros(0)
        return np.zeros(0, dtype=np.int64), empty, empty
    grid = np.linspace(0.0, 1.0, _GRID + 1)
    p = curves.p_end[todo, None] * grid[None, :]
    c = todo[:, None]
    curvature, rate = curves.curvature_rate(c, p)
    curvature, rate = np.nan_to_num(curvature), np.nan_to_num(rate)
    density = np.maximum(np.sqrt(np.abs(rate) * np.maximum(lever, 1e-3)[:, None] / (_HEADING_SPREAD * budget)),
                         np.abs(curvature) / _MAX_TURN)
    ds = np.diff(curves.table[todo], axis=1)
    steps = 0.5 * (density[:, 1:] + density[:, :-1]) * ds
    cumulative = np.concatenate([np.zeros((len(todo), 1)), np.cumsum(steps, axis=1)], axis=1)
    parts = np.minimum(np.maximum(1, np.ceil(cumulative[:, -1])), max_pieces + 1).astype(np.int64)
    owner = np.repeat(np.arange(len(todo)), parts + 1)
    k = np.arange(len(owner)) - np.repeat(np.cumsum(parts + 1) - (parts + 1), parts + 1)
    target = cumulative[owner, -1] * k / np.repeat(parts, parts + 1)
    # p where the cumulative count reaches each target, linear inside its grid cell
    cell = np.clip((cumulative[owner, 1:] <= target[:, None]).sum(axis=1), 0, _GRID - 1)
    low, high = cumulative[owner, cell], cumulative[owner, cell + 1]
    fraction = np.divide(target - low, high - low, out=np.zeros_like(target), where=high > low)
    fraction = np.clip(fraction, 0.0, 1.0)
    knots = p[owner, cell] + fraction * (p[owner, cell + 1] - p[owner, cell])
    knots[k == 0] = 0.0
    last = k == np.repeat(parts, parts + 1)
    knots[last] = p[owner[last], -1]
    start = np.flatnonzero(~last)
    return todo[owner[start]], knots[start], knots[start + 1]


def _grouped_cumsum(values: np.ndarray, first: np.ndarray) -> np.ndarray:
    """Cumulative sums restarting at every ``first`` element (inclusive)."""
    total = np.cumsum(values)
    starts = np.flatnonzero(first)
    before = total[starts] - values[starts]
    return total - np.repeat(before, np.diff(np.r_[starts, len(values)]))


def _arc_chains(curves, curve, pa, pb, used, lever, budget):
    """One arc per piece [p_a, p_b] (a flat array in curve and s order), chained G1 from each curve's start
    pose: ((s, x, y, heading, curvature, length) per piece, largest border deviation per piece, per curve
    whether the chain ends where the curve does, within JOINT).

    Each arc is exactly as long as the curve between its knots, so s is the curve's arc length at every joint
    and the pieces sum to the curve's length. The chain's heading is linear in s on each piece, through the
    curve's heading at the knots shifted by the mean of its error on the pieces on either side: the heading of
    a chord through a curving heading lies to one side of it on every piece, which would add up to a drift of
    the position; shifted, the error changes sign on each piece, so the position stays on the curve (and the
    largest heading error is k' h^2 / 12 instead of / 8). What little is left at the end is closed by the
    smallest change of the knot headings that moves the chain's end onto the curve's end."""
    first = np.r_[True, curve[1:] != curve[:-1]]
    last = np.r_[curve[1:] != curve[:-1], True]
    sa, sb = _s_of(curves, curve, pa, used), _s_of(curves, curve, pb, used)
    h = sb - sa
    xa, ya, raw_a = curves.pose(curve, pa)
    xb, yb, raw_b = curves.pose(curve, pb)
    # the curve's heading, unwrapped along each curve (a piece turns less than _MAX_TURN)
    turn = _wrap(raw_b - raw_a)
    start_heading = np.repeat(raw_a[first], np.diff(np.r_[np.flatnonzero(first), len(curve)]))
    heading_b = start_heading + _grouped_cumsum(turn, first)
    heading_a = heading_b - turn
    # the curve at Gauss-Legendre nodes of each piece (s-weights for the mean error, and the check points)
    pn = pa[:, None] + (pb - pa)[:, None] * _NODES[None, :]
    cn = curve[:, None]  # broadcast, not repeated: gathering coefficients per node is what costs
    un = curves.arc_length_along(curve, pa, pb, _NODES)
    xn, yn, raw_n = curves.pose(cn, pn)
    heading_n = heading_a[:, None] + _wrap(raw_n - raw_a[:, None])
    weight = _WEIGHTS[None, :] * curves.speed(cn, pn) * (pb - pa)[:, None]
    with np.errstate(all="ignore"):
        chord_heading = heading_a[:, None] + un / h[:, None] * turn[:, None]
        mean_error = np.nan_to_num((weight * (chord_heading - heading_n)).sum(axis=1) / h)
    shift = np.where(first, 0.0, -0.5 * (np.r_[0.0, mean_error[:-1]] + mean_error))
    knot = heading_a + shift  # the chain's heading at each piece's start; at a curve's end the curve's
    end_heading = heading_b[last]
    weight = (lever[curve] + h) / budget
    frozen = np.zeros(len(knot), dtype=bool)
    origin = xa[first] + 1j * ya[first]
    target = xb[last] + 1j * yb[last] + curves.overrun[curve[last]] * np.exp(1j * end_heading)
    span = np.r_[0.0, h[:-1]] + h  # a knot's share of the chain: half of each piece it joins
    n_curves = len(curves.p_end)
    owner = np.cumsum(first) - 1  # each piece's curve, numbered among the curves here
    counts = np.diff(np.r_[np.flatnonzero(first), len(curve)])
    # the end moves by i e^{i heading} (half the pieces beside it) per radian of an inner knot's heading
    # where the curve itself turns so little that CARLA would misplace an arc (the chain's own turns move with
    # the closure, which would pin a piece flat that the closure then needs to bend)
    with np.errstate(all="ignore"):
        nearly_flat = np.abs(turn) < MIN_CURVATURE * h
    for closing in range(_CLOSURE_STEPS + 1):
        if closing in _STRAIGHTEN_AT:  # once before closing, once after (closing makes more pieces flat)
            knot, straight = _straightened(knot, end_heading, first, last, weight)
            frozen |= straight
        knot_b = np.r_[knot[1:], 0.0]
        knot_b[last] = end_heading
        # a nearly flat piece is a line along its chord (the arc's chord has the mean of its end headings)
        step = h * np.where(nearly_flat, np.exp(0.5j * (knot + knot_b)), _chord(knot, knot_b))
        start = np.repeat(origin, counts) + _grouped_cumsum(step, first) - step
        miss = (start + step)[last] - target
        if closing == _CLOSURE_STEPS:
            break
        jx = np.where(first | frozen, 0.0, -np.sin(knot) * 0.5 * span)
        jy = np.where(first | frozen, 0.0, np.cos(knot) * 0.5 * span)
        m11, m12, m22 = (np.bincount(owner, weights, len(counts)) for weights in (jx * jx, jx * jy, jy * jy))
        regular = 1e-12 * (m11 + m22)  # a straight chain cannot move its end along itself
        det = (m11 + regular) * (m22 + regular) - m12 * m12
        det = np.where(det > 0.0, det, np.inf)  # a single arc: no inner knot to turn
        lx = -((m22 + regular) * miss.real - m12 * miss.imag) / det
        ly = -((m11 + regular) * miss.imag - m12 * miss.real) / det
        knot = knot + jx * lx[owner] + jy * ly[owner]
    closed = np.zeros(n_curves, dtype=bool)
    closed[curve[last]] = np.abs(miss) <= JOINT
    with np.errstate(all="ignore"):
        curvature = np.where(nearly_flat, 0.0, (knot_b - knot) / h)
    heading = np.where(nearly_flat, 0.5 * (knot + knot_b), knot)  # each piece's own heading at its start
    # the chain at the nodes and at both ends of each piece, against the curve at the same s (a knot's error
    # is both pieces' it joins: a long piece before it can be what puts it off; a line's own heading at its
    # end is not the next piece's)
    chain_heading = heading[:, None] + curvature[:, None] * un
    chain = start[:, None] + un * _chord(heading[:, None], chain_heading)
    inside = np.abs(chain - (xn + 1j * yn)) + lever[curve][:, None] * np.abs(chain_heading - heading_n)
    at_knot = np.abs(start - (xa + 1j * ya)) + lever[curve] * np.abs(heading - heading_a)
    at_end = np.where(last, 0.0, np.r_[at_knot[1:], 0.0])
    line_end = np.abs(start + step - (xb + 1j * yb)) + lever[curve] * np.abs(heading - heading_b)
    at_end = np.where(nearly_flat, np.maximum(at_end, line_end), at_end)
    deviation = np.maximum(inside.max(axis=1), np.maximum(at_knot, at_end))
    deviation = np.where(np.isfinite(curvature), deviation, np.inf)
    # a line may use only part of the budget for the turn it misses (half its knots' difference at either end):
    # the closure must make that up on the pieces before it, and a long line leaves them none. The knots' own
    # shift (the mean heading error of the pieces around them) is judged like any piece's: it does not shrink
    # when the line is split, so a line that carried it at a share of the budget could never fit
    missed_turn = 0.5 * (lever[curve] + h) * np.abs(knot_b - knot) / _FLAT_LINE_SHARE
    deviation = np.where(nearly_flat, np.maximum(deviation, missed_turn), deviation)
    return (sa, start.real, start.imag, _wrap(heading), curvature, h), deviation, closed


def _straightened(knot, end_heading, first, last, weight):
    """Knot headings with every run of pieces that turn so little that a line would do (``weight``: border
    deviation per radian of heading error, over the budget) made straight, and which knots that froze.

    CARLA evaluates an arc through its centre in single precision: radius * cos(heading) rounded to a float,
    so an arc of 10 km radius is a millimetre off there, one of 500 km (the piece at a curve's inflection) a
    few centimetres. A line is exact in every reader. The run's pieces share one heading -- the curve's at its
    start or end when the run reaches it, else the mean of the run's knots -- and so do the knots on either
    side, which keeps the chain G1; the closure leaves them alone."""
    knot_b = np.r_[knot[1:], 0.0]
    knot_b[last] = end_heading
    flat = np.abs(knot_b - knot) * weight <= _FLAT_SHARE
    frozen = np.zeros(len(knot), dtype=bool)
    if not flat.any():
        return knot, frozen
    run = np.cumsum(flat & (first | ~np.r_[False, flat[:-1]])) - 1
    pieces = np.flatnonzero(flat)
    runs = run[pieces]
    n_runs = int(runs.max()) + 1
    run_first = np.full(n_runs, len(knot))
    run_last = np.full(n_runs, -1)
    np.minimum.at(run_first, runs, pieces)
    np.maximum.at(run_last, runs, pieces)
    at_start, at_end = first[run_first], last[run_last]
    after = knot_b[run_last]  # the knot after the run: the next piece's start, or the curve's end
    mean = (np.bincount(runs, knot[pieces], n_runs) + after) / (np.bincount(runs, minlength=n_runs) + 1.0)
    heading = np.where(at_start, knot[run_first], np.where(at_end, after, mean))
    # a run may turn no more in all than one piece may: made a line, its heading is off by up to that much
    high, low, heavy = after.copy(), after.copy(), np.zeros(n_runs)
    np.maximum.at(high, runs, knot[pieces])
    np.minimum.at(low, runs, knot[pieces])
    np.maximum.at(heavy, runs, weight[pieces])
    usable = (high - low) * heavy <= _FLAT_SHARE
    usable &= ~(at_start & at_end)  # a run over the whole curve: the curve is no line, or it would be one
    mine = pieces[usable[runs]]
    knot = knot.copy()
    knot[mine] = heading[run[mine]]
    following = run_last[usable & ~at_end] + 1
    knot[following] = heading[usable & ~at_end]
    frozen[mine] = True
    frozen[following] = True
    return knot, frozen


_GL9, _GL9_WEIGHTS = np.polynomial.legendre.leggauss(9)
#: Gauss-Legendre nodes on [0, 1] (an odd count: the middle of a piece, where its heading error peaks, is one)
_NODES = 0.5 * (_GL9 + 1.0)
_WEIGHTS = 0.5 * _GL9_WEIGHTS
#: a piece turns at most this much (rad), so that headings unwrap along a curve
_MAX_TURN = 1.0
#: a piece whose turn moves the widest lane border by less than this share of the budget is made a line
_FLAT_SHARE = 0.25
#: share of the budget a piece made a line for being nearly flat (MIN_CURVATURE) may use
_FLAT_LINE_SHARE = 0.5
#: the chain's largest heading error on a piece of length h over a curvature changing at rate k'
_HEADING_SPREAD = 10.0
#: rounds of fitting and splitting before a curve is given up
_MAX_ROUNDS = 12
_CLOSURE_STEPS = 4
_STRAIGHTEN_AT = (0, 2)
