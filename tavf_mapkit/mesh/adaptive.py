"""Adaptive samples in s: as few cross-sections as keep the lane mesh within ``eps`` of the exact surface.

Every lane section starts with its own breakpoints (section ends, planView geometry starts where the
reference line may kink -- not where a line or arc continues into the next geometry G1 --, elevation /
superelevation / laneOffset records, lane width / border / height records), so every kink of the exact
surface is a sample. Then each segment [a, b] is checked at 1/4, 1/2 and 3/4 of its length for every lane of
the section at once: on each border the chord against the exact border point at the same s (3D distance),
inside the lane the quad's diagonal against the exact point at the same (s, t) (distance across the surface,
along e_h -- along the surface the borders bound the mesh). The chord error of a curve grows like
curvature * ds^2 / 8, with lateral terms from t * heading change, width cubics and elevation /
superelevation second derivatives; measuring it rather than bounding it catches all of them. Segments that
miss are halved, all segments of the map in one vectorised pass per level.

Both are upper bounds of the distance between the exact surface and the mesh at those places.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tavf_mapkit.opendrive.geometry import GeometryKind
from tavf_mapkit.opendrive.sampling import sample_lanes_at
from tavf_mapkit.opendrive.surface import surface_frame

CHECK_FRACTIONS = np.array([0.0, 0.25, 0.5, 0.75, 1.0])
MIN_SEGMENT = 1e-3        # m: below this a failing segment is a discontinuity of the data, not a curve
HEIGHT_STEP = 1e-3        # m: lane height records are steps; a sample this far before keeps the step sharp
LEFT_LIMIT = 1e-7         # m: s - LEFT_LIMIT evaluates the record / geometry that ends at a breakpoint
CONTINUOUS = 1e-4         # m: cross-sections closer than this on both sides of a breakpoint are one
SMOOTH_JOINT = 1e-6       # m, rad: a geometry that starts this close to the end of the one before continues it
#: segments (and breakpoints) sampled per call: a region's millions of segments at once would be more lane samples
#: than a map's allocation budget (Columbus: 5 M), the lanes of a few thousand are a few hundred thousand
SEGMENTS_PER_CALL = 16_384


@dataclass(frozen=True)
class AdaptiveSamples:
    """Final samples per lane section (grouped by section, ascending s) and what the check measured."""

    section: np.ndarray        # (n,) section row of NetworkArrays
    s: np.ndarray              # (n,)
    max_deviation: float       # largest check-point deviation of a final segment longer than MIN_SEGMENT
    discontinuities: int       # breakpoints where the exact surface jumps (kinks of the reference line)
    unresolved: int            # final segments that still missed eps at MIN_SEGMENT
    segments: int


def _section_keys(arrays) -> np.ndarray:
    return arrays.section_road + arrays.section_s0 / arrays.span


def _road_breaks(arrays, group: np.ndarray, s: np.ndarray):
    """(section, s) of road-level record starts (geometry, elevation, ...)."""
    if not len(s):
        return np.zeros(0, dtype=np.int64), np.zeros(0)
    keys = _section_keys(arrays)
    section = np.clip(np.searchsorted(keys, group + s / arrays.span, side="right") - 1, 0, len(keys) - 1)
    return section, s


def smooth_geometry_starts(table, rows: np.ndarray | None = None) -> np.ndarray:
    """Per row of a GeometryTable (of ``rows``, ascending, when given: each answer is the one for the whole
    table, a geometry being evaluated alike whatever else is): whether the geometry continues the line or arc
    before it on its road G1 (it starts where that one ends, with its heading, to SMOOTH_JOINT): no kink of the
    surface there, so no breakpoint. A chain of arcs (opendrive/repair_curves.py: tens of thousands on a city)
    would otherwise put a cross-section at every joint, however straight the road."""
    rows = np.arange(len(table)) if rows is None else np.asarray(rows, dtype=np.int64)
    smooth = np.zeros(len(rows), dtype=bool)
    if len(table) < 2 or not len(rows):
        return smooth
    before = np.maximum(rows - 1, 0)
    closed_form = np.isin(table.kind[before], (int(GeometryKind.LINE), int(GeometryKind.ARC)))
    which = np.flatnonzero((rows >= 1) & (table.group[rows] == table.group[before]) & closed_form
                           & (table.length[before] > 0))
    before, after = before[which], rows[which]
    x, y, heading, _ = table.evaluate(before, table.length[before])
    turn = np.abs((heading - table.hdg[after] + np.pi) % (2.0 * np.pi) - np.pi)
    smooth[which] = ((np.hypot(x - table.x[after], y - table.y[after]) <= SMOOTH_JOINT) & (turn <= SMOOTH_JOINT)
                     & (np.abs(table.s[before] + table.length[before] - table.s[after]) <= SMOOTH_JOINT))
    return smooth


def _geometry_sections(arrays) -> np.ndarray:
    """The section row each geometry's start falls in (``_road_breaks``), for the whole map once (kept with the
    map's tables): a batch of the mesher then evaluates the joints of its own sections' geometries only, not
    the 5 million of a city's (which took 0.8 GB and most of the time of every batch)."""
    cached = arrays.__dict__.get("_geometry_sections")
    if cached is None:
        g = arrays.geometries
        cached = _road_breaks(arrays, g.group, g.s)[0]
        object.__setattr__(arrays, "_geometry_sections", cached)
    return cached


def initial_breaks(arrays, max_segment: float, only: np.ndarray | None = None):
    """Sorted unique (section, s) breakpoints of every section with positive length (of the ``only`` sections,
    section rows, when given: each section's breakpoints depend on that section alone)."""
    sections, values = [], []
    n = len(arrays.section_s0)
    sections += [np.arange(n), np.arange(n)]
    values += [arrays.section_s0, arrays.section_end]
    g = arrays.geometries
    if only is None:
        kinks = ~smooth_geometry_starts(g)
        kink_group, kink_s = g.group[kinks], g.s[kinks]
    else:
        # only the geometries whose start falls in a wanted section: the others' breakpoints are dropped below
        wanted = np.zeros(n, dtype=bool)
        wanted[np.asarray(only, dtype=np.int64)] = True
        rows = np.flatnonzero(wanted[_geometry_sections(arrays)])
        kinks = ~smooth_geometry_starts(g, rows)
        kink_group, kink_s = g.group[rows[kinks]], g.s[rows[kinks]]
    for group, s in ((kink_group, kink_s), (arrays.elevation.group, arrays.elevation.s0),
                     (arrays.superelevation.group, arrays.superelevation.s0),
                     (arrays.lane_offset.group, arrays.lane_offset.s0)):
        sec, ss = _road_breaks(arrays, group, s)
        sections.append(sec)
        values.append(ss)
    for table in (arrays.lane_width, arrays.lane_border):
        sections.append(arrays.lane_section[table.group])
        values.append(table.s0)
    for table in (arrays.lane_height_inner,):
        sec = arrays.lane_section[table.group]
        sections += [sec, sec]
        values += [table.s0, table.s0 - HEIGHT_STEP]
    section = np.concatenate(sections).astype(np.int64)
    s = np.concatenate(values).astype(float)
    if only is not None:
        wanted = np.zeros(n, dtype=bool)
        wanted[np.asarray(only, dtype=np.int64)] = True
        section, s = section[wanted[section]], s[wanted[section]]
    inside = (s >= arrays.section_s0[section]) & (s <= arrays.section_end[section])
    section, s = section[inside], s[inside]
    order = np.lexsort((s, section))
    section, s = section[order], s[order]
    # merge breakpoints closer than a micrometre (netconvert writes geometries of zero length)
    keep = np.ones(len(s), dtype=bool)
    keep[1:] = (section[1:] != section[:-1]) | (s[1:] - s[:-1] > 1e-6)
    # a section's end must survive the merge: replace the last kept value of each section by its end
    section, s = section[keep], s[keep]
    last = np.ones(len(s), dtype=bool)
    last[:-1] = section[1:] != section[:-1]
    s[last] = arrays.section_end[section[last]]
    # segments
    same = section[1:] == section[:-1]
    a, b, seg_section = s[:-1][same], s[1:][same], section[:-1][same]
    positive = b - a > 1e-9
    a, b, seg_section = a[positive], b[positive], seg_section[positive]
    # long straight segments are cut so that tiles and collision triangles stay reasonable
    pieces = np.maximum(1.0, np.ceil((b - a) / max_segment))
    arrays.budget.check(arrays.section_road[seg_section], pieces, f"mesh segments of at most {max_segment:g} m")
    pieces = pieces.astype(np.int64)
    k = np.arange(int(pieces.sum())) - np.repeat(np.cumsum(pieces) - pieces, pieces)
    length = np.repeat((b - a) / pieces, pieces)
    start = np.repeat(a, pieces) + k * length
    last_piece = k == np.repeat(pieces, pieces) - 1
    end = np.where(last_piece, np.repeat(b, pieces), start + length)
    return np.repeat(seg_section, pieces), start, end, last_piece


def segment_deviation(odr, seg_section: np.ndarray, a: np.ndarray, b: np.ndarray,
                      at_break: np.ndarray | None = None) -> np.ndarray:
    """Largest parametric deviation (m) of the mesh from the exact surface on each segment, over all lanes.

    A segment that ends at a breakpoint is evaluated up to the left limit there (b - LEFT_LIMIT): records
    and geometries are right-continuous, and a kink must not be smeared into the segment before it.
    """
    n = len(a)
    if not n:
        return np.zeros(0)
    if n > SEGMENTS_PER_CALL:  # each segment's deviation is its own: batches give the same numbers
        return np.concatenate([
            segment_deviation(odr, seg_section[i:i + SEGMENTS_PER_CALL], a[i:i + SEGMENTS_PER_CALL],
                              b[i:i + SEGMENTS_PER_CALL], None if at_break is None else at_break[i:i + SEGMENTS_PER_CALL])
            for i in range(0, n, SEGMENTS_PER_CALL)])
    f = CHECK_FRACTIONS
    k = len(f)
    s = (a[:, None] + (b - a)[:, None] * f[None, :]).ravel()
    s[k - 1::k] = b if at_break is None else np.where(at_break, b - LEFT_LIMIT, b)
    sampling = sample_lanes_at(odr, np.repeat(seg_section, k), s)
    if not len(sampling.pair_lane):
        return np.zeros(n)
    # pairs are lane by lane in sample order, and each segment contributes k consecutive samples
    t_in = sampling.t_inner.reshape(-1, k)
    t_out = sampling.t_outer.reshape(-1, k)
    segment = sampling.pair_sample.reshape(-1, k)[:, 0] // k
    fr = f[None, :]
    t_diagonal = (1.0 - fr) * t_in[:, :1] + fr * t_out[:, -1:]
    deviation = np.zeros(len(t_in))
    _, e_h = surface_frame(sampling.heading, sampling.slope, sampling.superelevation)
    for t in (t_in, t_out, t_diagonal):
        # the diagonal's ends are the quad's inner-start and outer-end corners, so for all three curves the
        # first and last points are mesh vertices
        points = sampling.points_at(t.ravel()).reshape(-1, k, 3)
        start, end = points[:, 0], points[:, -1]
        chord = start[:, None, :] * (1.0 - fr)[..., None] + end[:, None, :] * fr[..., None]
        offset = points[:, 1:-1] - chord[:, 1:-1]
        if t is t_diagonal:
            # inside a lane only the distance across the surface counts: along it the borders bound the
            # mesh, and a trapezoid's diagonal runs at another s than the exact parameter (no error)
            error = np.abs(np.einsum("ijk,ijk->ij", offset, e_h[sampling.pair_sample].reshape(-1, k, 3)[:, 1:-1]))
            error = error.max(axis=1)
        else:
            error = np.linalg.norm(offset, axis=2).max(axis=1)
        deviation = np.maximum(deviation, error)
    out = np.zeros(n)
    np.maximum.at(out, segment, deviation)
    return out


def adaptive_samples(odr, eps: float = 0.05, max_segment: float = 50.0, max_levels: int = 40,
                     sections: np.ndarray | None = None) -> AdaptiveSamples:
    """Samples per lane section such that the lane mesh is within ``eps`` of the exact surface (of the given
    section rows only, when ``sections`` is given; every section's samples are its own)."""
    if not (eps > 0 and np.isfinite(eps)):
        raise ValueError("eps must be a positive number of metres")
    arrays = odr.arrays
    seg_section, a, b, at_break = initial_breaks(arrays, max_segment, sections)
    done = []
    for _ in range(max_levels):
        if not len(a):
            break
        error = segment_deviation(odr, seg_section, a, b, at_break)
        error = np.where(np.isfinite(error), error, np.inf)
        ok = (error <= eps) | (b - a <= MIN_SEGMENT)
        done.append((seg_section[ok], a[ok], b[ok], at_break[ok], error[ok]))
        miss = ~ok
        sec, lo, hi, brk = seg_section[miss], a[miss], b[miss], at_break[miss]
        mid = 0.5 * (lo + hi)
        # halves: the left one ends at a plain sample, the right one keeps the break flag
        seg_section = np.concatenate([sec, sec])
        a = np.concatenate([lo, mid])
        b = np.concatenate([mid, hi])
        at_break = np.concatenate([np.zeros(len(sec), dtype=bool), brk])
        order = np.lexsort((a, seg_section))
        seg_section, a, b, at_break = seg_section[order], a[order], b[order], at_break[order]
    if len(a):  # out of levels: keep what is left
        done.append((seg_section, a, b, at_break, np.full(len(a), np.inf)))
    if not done:
        return AdaptiveSamples(np.zeros(0, dtype=np.int64), np.zeros(0), 0.0, 0, 0, 0)
    section, start, end, at_break, error = (np.concatenate(parts) for parts in zip(*done))
    order = np.lexsort((start, section))
    section, start, end, at_break, error = (v[order] for v in (section, start, end, at_break, error))

    # where the exact surface jumps at a breakpoint (a kink of the reference line moves the lane borders),
    # the segment before it ends at the left limit and the next one starts at the right value
    jump = np.zeros(len(end), dtype=bool)
    candidates = np.flatnonzero(at_break)
    for first in range(0, len(candidates), SEGMENTS_PER_CALL):
        batch = candidates[first:first + SEGMENTS_PER_CALL]
        pair_s = np.stack([end[batch] - LEFT_LIMIT, end[batch]], axis=1).ravel()
        sampling = sample_lanes_at(odr, np.repeat(section[batch], 2), pair_s)
        if len(sampling.pair_lane):
            gap = np.zeros(len(batch))
            for t in (sampling.t_inner, sampling.t_outer):
                points = sampling.points_at(t)
                left, right = points[0::2], points[1::2]
                np.maximum.at(gap, sampling.pair_sample[0::2] // 2, np.linalg.norm(left - right, axis=1))
            jump[batch] = gap > CONTINUOUS
    last = np.ones(len(section), dtype=bool)
    last[:-1] = section[1:] != section[:-1]
    end_sample = np.where(jump, end - LEFT_LIMIT, end)
    # samples: every segment start, the left limit of every jump, and each section's last end
    extra = jump & ~last
    sample_section = np.concatenate([section, section[extra], section[last]])
    sample_s = np.concatenate([start, end_sample[extra], end_sample[last]])
    order = np.lexsort((sample_s, sample_section))
    resolved = end - start > MIN_SEGMENT
    return AdaptiveSamples(
        sample_section[order], sample_s[order],
        max_deviation=float(np.max(error[resolved], initial=0.0)),
        discontinuities=int(np.count_nonzero(jump)),
        unresolved=int(np.count_nonzero(~resolved & (error > eps))),
        segments=len(start),
    )
