"""Where a car following a lane's centre line sweeps: the plan-view area a curb must leave free.

A car turning on a circle of radius R (its rear axle's midpoint on the lane centre line) sweeps beyond its
half width: the front overhangs outwards and, if the front axle follows the line instead, the rear wheels
cut inwards -- by about R - sqrt(R^2 - L^2) for a wheelbase L either way (the "curve widening" of road
design). netconvert draws junction corners around its connecting lanes' own shapes, often tighter than a
car turns, so a curb on such a corner would stand in the way of every car using the lane. The swept area of
a piece of centre line (PIECE samples) reaches DESIGN_HALF_WIDTH + that widening (at its sharpest point) +
MARGIN to both sides (inner and outer side of a turn swap with the direction of travel; one width keeps it
simple).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import manifold3d
import numpy as np
import shapely

from tavf_mapkit.mesh.exact import RunTable, run_cumsum
from tavf_mapkit.mesh.kinds import lane_kind_codes
from tavf_mapkit.mesh.labelled import KIND_CODE
from tavf_mapkit.opendrive.sampling import sample_lanes_at, section_samples

DESIGN_HALF_WIDTH = 1.0   # m: half the width of a large passenger car (design vehicle, mirrors folded)
DESIGN_WHEELBASE = 3.0    # m: its wheelbase (a Tesla Model S has 2.96 m)
MARGIN = 0.25             # m: how far a driver stays off a curb
STEP = 0.5                # m of s between centre-line samples
PIECE = 10                # samples per piece of centre line that gets one swept width
BOX_MARGIN = 1e-6         # m: a plan box test's allowance for the rounding of a box's bounds
QUAD_SEGMENTS = 2         # segments per quarter circle of the round ends (coarse: it is a clearance)
# m: the farthest a swept area (``swept_areas``) reaches from its centre line: the widest swept half width,
# widened as its round ends are
REACH = (DESIGN_HALF_WIDTH + DESIGN_WHEELBASE + MARGIN) / np.cos(np.pi / (4 * QUAD_SEGMENTS))


def swept_width(curvature: np.ndarray) -> np.ndarray:
    """Half width of the swept path at a plan-view curvature (1/m): half width + curve widening + margin."""
    radius = 1.0 / np.maximum(np.abs(curvature), 1e-9)
    wheelbase = DESIGN_WHEELBASE
    # no car follows a circle smaller than its wheelbase: the widening stops growing there
    widening = np.where(radius > wheelbase, radius - np.sqrt(np.maximum(radius**2 - wheelbase**2, 0.0)), wheelbase)
    return DESIGN_HALF_WIDTH + widening + MARGIN


def wheelbase_curvature(lane: np.ndarray, points: np.ndarray, window: float = DESIGN_WHEELBASE) -> np.ndarray:
    """Curvature (1/m, unsigned) at every point of polylines (runs of consecutive points with the same
    ``lane``): the heading change over one DESIGN_WHEELBASE (or ``window``) of arc length centred on the
    point (cut at the run's ends), over that length. A car smooths a kink over its own length, so a kink
    counts by its angle over a wheelbase, not as the infinite curvature of a corner. Each run is measured on
    its own, to the bit: a run's curvatures never depend on the runs around it."""
    return wheelbase_curvatures(lane, points, (window,))[0]


def wheelbase_curvatures(lane: np.ndarray, points: np.ndarray, windows) -> list[np.ndarray]:
    """``wheelbase_curvature`` over each of ``windows``, the same bits: arc lengths, headings and the search
    tables of the polylines are made once for all windows (route selection measures five on every bend of a
    region)."""
    n = len(points)
    step = np.hypot(*np.diff(points, axis=0).T) if n > 1 else np.zeros(0)
    # a repeated point has no heading: it takes the curvature of the point before
    repeat = np.r_[False, (lane[1:] == lane[:-1]) & (step <= 1e-9)]
    keep = np.flatnonzero(~repeat)
    lane, points = lane[keep], points[keep]
    back_to_all = np.cumsum(~repeat) - 1
    same = lane[1:] == lane[:-1]
    if not np.any(same):
        return [np.zeros(len(points))[back_to_all] for _ in windows]
    along = points[1:] - points[:-1]
    length = np.where(same, np.hypot(along[:, 0], along[:, 1]), 0.0)
    heading = np.arctan2(along[:, 1], along[:, 0])
    run = np.cumsum(np.r_[True, ~same]) - 1
    # arc length from the run's start (a crossing between runs has length 0)
    arc = run_cumsum(np.r_[0.0, length], run)
    segment = np.flatnonzero(same)  # segment k joins point k and k + 1
    seg_run = run[segment]
    # heading made continuous inside each run, from the run's first segment
    turn = (heading[segment[1:]] - heading[segment[:-1]] + np.pi) % (2 * np.pi) - np.pi
    turn = np.r_[0.0, np.where(seg_run[1:] == seg_run[:-1], turn, 0.0)]
    unwrapped = run_cumsum(turn, seg_run)
    middle = 0.5 * (arc[segment] + arc[segment + 1])
    first = np.flatnonzero(np.r_[True, seg_run[1:] != seg_run[:-1]])
    last = np.r_[first[1:], len(segment)] - 1
    runs = seg_run[first]
    lo, hi = np.full(run[-1] + 1, np.nan), np.full(run[-1] + 1, np.nan)
    lo[runs], hi[runs] = middle[first], middle[last]
    start, end = np.full(run[-1] + 1, np.nan), np.full(run[-1] + 1, np.nan)
    start[runs], end[runs] = arc[segment[first]], arc[segment[last] + 1]
    has = np.isfinite(lo[run])
    r = run[has]
    has_arc = arc[has]
    interp = RunTable(middle, seg_run).at(r)
    found = []
    for window in windows:
        half = 0.5 * window
        # headings are read between the run's first and last segment middles, so runs never mix
        back = np.clip(has_arc - half, lo[r], hi[r])
        ahead = np.clip(has_arc + half, lo[r], hi[r])
        change = np.abs(interp(ahead, unwrapped) - interp(back, unwrapped))
        span = np.minimum(has_arc + half, end[r]) - np.maximum(has_arc - half, start[r])
        curvature = np.zeros(len(points))
        curvature[has] = np.where(span > 1e-9, change / np.maximum(span, 1e-9), 0.0)
        found.append(curvature[back_to_all])
    return found


def swept_section(odr, near: np.ndarray, anchor: np.ndarray, roads: np.ndarray | None = None,
                  pieces: CentrePieces | None = None) -> manifold3d.CrossSection:
    """The swept paths of every driving lane (of the ``roads`` indices, when given) that comes within reach of
    the shapely geometries ``near``, as one manifold3d CrossSection in local x, y minus ``anchor`` (empty when
    none comes near). ``pieces``: ``CentrePieces`` made before for (at least) those roads."""
    pieces = CentrePieces.of(odr, roads) if pieces is None else pieces
    mine = np.arange(len(pieces.width)) if roads is None else np.flatnonzero(np.isin(pieces.road, roads))
    if not len(mine) or not len(near):
        return manifold3d.CrossSection()
    reach = float(pieces.width[mine].max())
    # only pieces whose box comes within reach of the box of ``near`` can be within reach of ``near``: their
    # LineStrings are made, the rest never are (making every piece's was a tenth of a region's mesh stage)
    bounds = shapely.bounds(near)  # NaN for an empty geometry, which is never within reach
    if np.all(np.isnan(bounds)):
        return manifold3d.CrossSection()
    low, high = np.nanmin(bounds[:, :2], axis=0) - reach, np.nanmax(bounds[:, 2:], axis=0) + reach
    close = np.all((pieces.low[mine] <= high + BOX_MARGIN) & (pieces.high[mine] >= low - BOX_MARGIN), axis=1)
    candidates = mine[close]
    if not len(candidates):
        return manifold3d.CrossSection()
    _, hit = shapely.STRtree(pieces.lines(candidates)).query(near, predicate="dwithin", distance=reach)
    hit = candidates[np.unique(hit)]
    if not len(hit):
        return manifold3d.CrossSection()
    # a buffer of a line has no holes
    rings = shapely.get_exterior_ring(shapely.get_parts(swept_areas(pieces.lines(hit), pieces.width[hit])))
    coordinates, ring = shapely.get_coordinates(rings, return_index=True)
    cuts = np.flatnonzero(np.diff(ring)) + 1
    return manifold3d.CrossSection([part[:-1] - anchor for part in np.split(coordinates, cuts)],
                                   manifold3d.FillRule.Positive)


def swept_areas(lines: np.ndarray, width: np.ndarray) -> np.ndarray:
    """The swept area of every centre-line piece (``centre_pieces``' lines and half widths), one shapely
    polygon per piece: the piece buffered by its width, widened so that the polygons of its round ends and
    joints circumscribe their circles."""
    # round ends and joints are polygons with QUAD_SEGMENTS sides per quarter: widen them so they circumscribe
    circumscribe = 1.0 / np.cos(np.pi / (4 * QUAD_SEGMENTS))
    return shapely.orient_polygons(shapely.buffer(lines, width * circumscribe, quad_segs=QUAD_SEGMENTS))


def followable(width: np.ndarray) -> np.ndarray:
    """Swept half widths (``swept_width``) with every piece sharper than a car can follow as drawn -- a
    radius below the wheelbase, where the widening stops at the wheelbase: U-turn connectors and polyline
    kinks, which a car cuts (and the twin does not drive) -- at the straight width instead. For solids that
    must leave free where cars drive but would lose far too much to the capped widening (buildings)."""
    capped = width >= DESIGN_HALF_WIDTH + DESIGN_WHEELBASE + MARGIN
    return np.where(capped, DESIGN_HALF_WIDTH + MARGIN, width)


def centre_pieces(odr, roads: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every driving lane's centre line (of the ``roads`` indices, when given) in pieces of PIECE samples
    (shapely LineStrings, plan view), the swept half width of each piece (at its sharpest point) and its road.
    A piece depends on its own lane alone."""
    pieces = CentrePieces.of(odr, roads)
    return pieces.lines(np.arange(len(pieces.width))), pieces.width, pieces.road


@dataclass(frozen=True, eq=False)
class CentrePieces:
    """``centre_pieces`` kept as coordinates: each piece's points, plan box, swept half width and road. The
    LineStrings are made for the pieces asked for (``lines``), the same as ``centre_pieces``' ones."""

    points: np.ndarray  # (n, 2) every piece's points, piece after piece
    start: np.ndarray   # (m + 1,) where each piece's points start in ``points`` (and the end)
    width: np.ndarray   # (m,) swept half width
    road: np.ndarray    # (m,) road index
    low: np.ndarray     # (m, 2) plan box
    high: np.ndarray
    made_for: np.ndarray | None = None  # the road indices asked for (None: every road), pieces or not

    @classmethod
    def of(cls, odr, roads: np.ndarray | None = None, known: CentrePieces | None = None) -> CentrePieces:
        """Every driving lane's centre line (of the ``roads`` indices, when given) in pieces of PIECE samples.
        ``known``: pieces made before for other roads; the roads both ask for are taken from it, not sampled
        again (a piece depends on its own lane alone, so they are the same pieces, in the same order). Groups of
        junction clusters taken row by row share about a quarter of their roads with the group before."""
        if known is not None and roads is not None and known.made_for is not None:
            return cls._reusing(odr, np.unique(np.asarray(roads, dtype=np.int64)), known)
        made = cls._sampled(odr, roads)
        return made if roads is None else replace(made, made_for=np.unique(np.asarray(roads, dtype=np.int64)))

    @classmethod
    def _reusing(cls, odr, roads: np.ndarray, known: CentrePieces) -> CentrePieces:
        missing = roads[~np.isin(roads, known.made_for)]
        fresh = cls._sampled(odr, missing)
        kept = known._take(np.flatnonzero(np.isin(known.road, roads)))
        both = cls._join(kept, fresh)
        # each road's pieces come whole from one of them: a stable sort by road is the order ``of`` makes
        return replace(both._take(np.argsort(both.road, kind="stable")), made_for=roads)

    def _take(self, index: np.ndarray) -> CentrePieces:
        """The pieces at ``index``, in that order."""
        index = np.asarray(index, dtype=np.int64)
        counts = self.start[index + 1] - self.start[index]
        first = np.repeat(self.start[index], counts)
        within = np.arange(int(counts.sum())) - np.repeat(np.cumsum(counts) - counts, counts)
        return CentrePieces(self.points[first + within], np.r_[0, np.cumsum(counts)].astype(np.int64),
                            self.width[index], self.road[index], self.low[index], self.high[index])

    @staticmethod
    def _join(a: CentrePieces, b: CentrePieces) -> CentrePieces:
        return CentrePieces(np.concatenate([a.points, b.points]), np.r_[a.start, a.start[-1] + b.start[1:]],
                            np.concatenate([a.width, b.width]), np.concatenate([a.road, b.road]),
                            np.concatenate([a.low, b.low]), np.concatenate([a.high, b.high]))

    @classmethod
    def _sampled(cls, odr, roads: np.ndarray | None) -> CentrePieces:
        arrays = odr.arrays
        rows = (np.arange(len(arrays.lane_id)) if roads is None
                else np.flatnonzero(np.isin(arrays.section_road[arrays.lane_section], roads)))
        driving = np.zeros(len(arrays.lane_id), dtype=bool)
        driving[rows] = lane_kind_codes(arrays.lane_type[rows]) == KIND_CODE["driving"]
        sections = np.unique(arrays.lane_section[driving])
        if not len(sections):
            return cls(np.zeros((0, 2)), np.zeros(1, dtype=np.int64), np.zeros(0), np.zeros(0, dtype=np.int64),
                       np.zeros((0, 2)), np.zeros((0, 2)))
        sampling = sample_lanes_at(odr, *section_samples(arrays, STEP, True, sections))
        keep = driving[sampling.pair_lane]
        lane = sampling.pair_lane[keep]
        centre = sampling.center_points(with_height=False)[keep, :2]
        curvature = wheelbase_curvature(lane, centre)
        same = lane[1:] == lane[:-1]
        # pieces: PIECE samples each, the first sample of the next piece repeated so that pieces join
        run_start = np.flatnonzero(np.r_[True, ~same])
        index_in_run = np.arange(len(lane)) - np.repeat(run_start, np.diff(np.r_[run_start, len(lane)]))
        piece = np.cumsum(np.r_[True, ~same] | ((index_in_run % PIECE == 0) & (index_in_run > 0))) - 1
        joint = np.flatnonzero((index_in_run % PIECE == 0) & (index_in_run > 0))
        point = np.concatenate([np.arange(len(lane)), joint])
        owner = np.concatenate([piece, piece[joint] - 1])
        order = np.lexsort((point, owner))
        point, owner = point[order], owner[order]
        counts = np.bincount(owner)
        usable = counts[owner] >= 2
        point, owner = point[usable], owner[usable]
        _, owner = np.unique(owner, return_inverse=True)
        width = np.zeros(owner.max(initial=-1) + 1)
        np.maximum.at(width, owner, swept_width(curvature[point]))
        road = np.zeros(len(width), dtype=np.int64)
        road[owner] = sampling.road_index[keep][point]
        points = centre[point]
        start = np.searchsorted(owner, np.arange(len(width) + 1))
        if not len(width):
            return cls(points, start, width, road, np.zeros((0, 2)), np.zeros((0, 2)))
        return cls(points, start, width, road, np.minimum.reduceat(points, start[:-1], axis=0),
                   np.maximum.reduceat(points, start[:-1], axis=0))

    def lines(self, index: np.ndarray) -> np.ndarray:
        """The LineStrings of the pieces at ``index`` (ascending or not), in that order."""
        index = np.asarray(index, dtype=np.int64)
        counts = self.start[index + 1] - self.start[index]
        if not len(index):
            return np.zeros(0, dtype=object)
        first = np.repeat(self.start[index], counts)
        within = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
        return shapely.linestrings(self.points[first + within], indices=np.repeat(np.arange(len(index)), counts))
