"""Geometry rules: reference-line contiguity, lengths, paramPoly3 arc length, lane widths and borders, profile
jumps, zero lengths, implausible numbers. Vectorised over the whole map (NetworkArrays), one pass per rule."""

from __future__ import annotations

import itertools

import numpy as np

from tavf_mapkit.opendrive.budget import ELEVATION_LIMIT, LATERAL_LIMIT, MIN_ROAD_LIMIT, WINDING
from tavf_mapkit.opendrive.cubic import cubic_minimum
from tavf_mapkit.opendrive.geometry import GeometryKind
from tavf_mapkit.opendrive.plausibility import COORDINATE_LIMIT
from tavf_mapkit.validate.context import angle_difference
from tavf_mapkit.validate.finding import ERROR, WARNING, Hit
from tavf_mapkit.validate.registry import rule

_GL_NODES, _GL_WEIGHTS = np.polynomial.legendre.leggauss(16)

ARC_LENGTH_CHUNK = 20_000  # curves per pass where each needs an arc-length table (bounded memory)


def _geometry_of_row(odr, table, row) -> tuple:
    """(road, geometry) of a row of the map's geometry table, whose rows are the roads' geometries road by road.
    Looked up per finding: a list of every (road, geometry) of the map would take the map's size again."""
    road_index = int(table.group[row])
    road = odr.roads[road_index]
    return road, road.reference_line.geometries[int(row) - int(np.searchsorted(table.group, road_index))]


def _joints(ctx):
    """For every pair of consecutive geometries of a road: (index of the first, end point/heading of the first)."""
    cache = ctx.notes.setdefault("_geometry_joints", {})
    if "value" not in cache:
        table = ctx.odr.arrays.geometries
        first = np.flatnonzero(table.group[:-1] == table.group[1:]) if len(table) > 1 else np.zeros(0, dtype=int)
        x, y, heading = np.empty(len(first)), np.empty(len(first)), np.empty(len(first))
        for start in range(0, len(first), ARC_LENGTH_CHUNK):  # a curve's end costs its arc-length table
            part = first[start:start + ARC_LENGTH_CHUNK]
            x[start:start + len(part)], y[start:start + len(part)], heading[start:start + len(part)], _ = \
                table.evaluate(part, table.length[part])
        cache["value"] = (table, first, x, y, heading)
    return cache["value"]


@rule("geometry.gap", ERROR, tolerance=0.001, unit="m",
      summary="Consecutive planView geometries of a road join: the end of one is the start of the next.",
      why="A gap is a hole in the road surface and a jump for anything driving along the reference line.")
def gap(ctx, rule):
    table, first, x, y, _ = _joints(ctx)
    distance = np.hypot(table.x[first + 1] - x, table.y[first + 1] - y)
    gaps = np.flatnonzero(distance > rule.tolerance)
    short = _param_poly3_shortfall(table, first[gaps])
    for k, missing in zip(gaps, short):
        road, geometry = _geometry_of_row(ctx.odr, table, first[k] + 1)
        why = (f" (the paramPoly3 before it is {missing:.4g} m longer than its @length, and s is arc length)"
               if missing > rule.tolerance else "")
        yield Hit(f"geometry at s={geometry.s:g} starts {distance[k]:.4g} m from where the previous one ends{why}",
                  road=road.id, s=geometry.s, line=geometry.line)


def _param_poly3_shortfall(table, rows: np.ndarray) -> np.ndarray:
    """Per geometry row: how much longer a paramPoly3's curve is than its @length (0 for other kinds)."""
    shortfall = np.zeros(len(rows))
    curves = np.flatnonzero(table.kind[rows] == int(GeometryKind.PARAM_POLY3))
    if len(curves):
        shortfall[curves] = param_poly3_arc_lengths(table, rows[curves]) - table.length[rows[curves]]
    return shortfall


@rule("geometry.kink", WARNING, tolerance=0.1, unit="deg",
      summary="Consecutive planView geometries of a road have the same heading where they join.",
      why="A kink is a heading jump: lane borders fan out or overlap at the joint and vehicles steer abruptly.")
def kink(ctx, rule):
    table, first, _, _, heading = _joints(ctx)
    difference = np.degrees(np.abs(angle_difference(table.hdg[first + 1], heading)))
    for k in np.flatnonzero(difference > rule.tolerance):
        road, geometry = _geometry_of_row(ctx.odr, table, first[k] + 1)
        yield Hit(f"heading changes by {difference[k]:.3g} deg where the geometry at s={geometry.s:g} begins",
                  road=road.id, s=geometry.s, line=geometry.line)


@rule("geometry.length", ERROR, tolerance=0.001, unit="m",
      summary="Geometry s values follow from the lengths (first at s=0, each at the previous s + length) and the "
              "geometries add up to the road's @length.",
      why="Readers locate a geometry by s; inconsistent s or lengths shift or cut the road and its lanes.")
def lengths(ctx, rule):
    tolerance = rule.tolerance
    for road_index in _roads_with_length_problems(ctx.odr.arrays, tolerance):
        road = ctx.odr.roads[road_index]
        geometries = road.reference_line.geometries
        if abs(geometries[0].s) > tolerance:
            yield Hit(f"first geometry starts at s={geometries[0].s:g}, not 0", road=road.id, s=geometries[0].s,
                      line=geometries[0].line)
        for before, after in itertools.pairwise(geometries):
            expected = before.s + before.length
            if abs(after.s - expected) > tolerance:
                yield Hit(f"geometry at s={after.s:g} should start at s={expected:.6g} (previous s + length)",
                          road=road.id, s=after.s, line=after.line)
        end = geometries[-1].s + geometries[-1].length
        if abs(end - road.length) > tolerance:
            yield Hit(f"geometries end at s={end:.6g} but the road's @length is {road.length:.6g} "
                      f"({end - road.length:+.4g} m)", road=road.id, line=road.line)


def _roads_with_length_problems(arrays, tolerance: float) -> list[int]:
    """Indices of the roads (in order) that geometry.length reports, found on the map's geometry table at once: the
    rule's per-road loop, with the same sums, then runs on these roads alone."""
    table = arrays.geometries
    if not len(table):
        return []
    group, s, length = table.group, table.s, table.length
    start = np.ones(len(group), dtype=bool)
    start[1:] = group[1:] != group[:-1]
    last = np.ones(len(group), dtype=bool)
    last[:-1] = start[1:]
    follows = ~start[1:]
    bad = [group[start & (np.abs(s) > tolerance)],
           group[1:][follows & (np.abs(s[1:] - (s[:-1] + length[:-1])) > tolerance)],
           group[last & (np.abs(s + length - arrays.road_length[group]) > tolerance)]]
    return np.unique(np.concatenate(bad)).tolist()


def param_poly3_arc_lengths(table, rows: np.ndarray) -> np.ndarray:
    """True arc length of paramPoly3 rows of a GeometryTable (composite 16-point Gauss-Legendre, 16 panels).

    Computed here rather than taken from the evaluator: the validator checks the file, not our reading of it.
    """
    panels = 16
    edges = np.linspace(0.0, 1.0, panels + 1)
    nodes = (0.5 * (edges[1:] - edges[:-1])[:, None] * (_GL_NODES + 1.0) + edges[:-1, None]).ravel()
    weights = (0.5 * (edges[1:] - edges[:-1])[:, None] * _GL_WEIGHTS).ravel()
    out = np.empty(len(rows))
    for start in range(0, len(rows), ARC_LENGTH_CHUNK):  # 256 nodes a curve: bounded memory on large maps
        part = rows[start:start + ARC_LENGTH_CHUNK]
        params = table.params[part]
        p_end = np.where(params[:, 8] > 0.5, 1.0, table.length[part])
        p = p_end[:, None] * nodes[None, :]
        du = params[:, 1:2] + p * (2.0 * params[:, 2:3] + 3.0 * params[:, 3:4] * p)
        dv = params[:, 5:6] + p * (2.0 * params[:, 6:7] + 3.0 * params[:, 7:8] * p)
        out[start:start + len(part)] = (np.hypot(du, dv) * weights).sum(axis=1) * p_end
    return out


@rule("geometry.param-poly3-length", WARNING, tolerance=0.01, unit="m",
      summary="A paramPoly3's true arc length equals its @length.",
      why="s along the road is arc length: read so (CARLA, libOpenDRIVE and we do), a curve longer than its @length "
          "ends early and leaves a gap before the next geometry or road, a shorter one stands still at its end; "
          "readers that spread @length over the curve place its lanes differently.")
def param_poly3_length(ctx, rule):
    table = ctx.odr.arrays.geometries
    rows = np.flatnonzero(table.kind == int(GeometryKind.PARAM_POLY3))
    if not len(rows):
        return
    true_length = param_poly3_arc_lengths(table, rows)
    difference = true_length - table.length[rows]
    for k in np.flatnonzero(np.abs(difference) > rule.tolerance):
        road, geometry = _geometry_of_row(ctx.odr, table, rows[k])
        effect = (f"s ends {difference[k]:.4g} m before the curve does, a gap at its end" if difference[k] > 0 else
                  f"s runs {-difference[k]:.4g} m past the curve's end, where the reference line stands still")
        yield Hit(f"paramPoly3 at s={geometry.s:g} is {true_length[k]:.6g} m long, @length says "
                  f"{geometry.length:.6g} ({difference[k]:+.4g} m): {effect}", road=road.id, s=geometry.s,
                  line=geometry.line)


@rule("geometry.negative-width", ERROR, tolerance=0.001, unit="m",
      summary="No lane width record becomes negative anywhere in its range (exact minimum of the cubic).",
      why="A negative width turns a lane inside out: its outer border crosses its inner border and the surface "
          "folds over the neighbouring lane.")
def negative_width(ctx, rule):
    arrays = ctx.odr.arrays
    widths = arrays.lane_width
    if not len(widths.s0):
        return
    length = widths.intervals(arrays.section_end[arrays.lane_section])
    minimum, where = cubic_minimum(widths.coefficients, length)
    active = ~arrays.lane_uses_border[widths.group] & (length > 0)
    rows = ctx.lane_rows
    reported = set()
    for k in np.flatnonzero(active & (minimum < -rule.tolerance)):
        lane_row = int(widths.group[k])
        if lane_row in reported:
            continue
        reported.add(lane_row)
        road, _, lane = rows[lane_row]
        s = float(widths.s0[k] + where[k])
        yield Hit(f"lane width reaches {minimum[k]:.4g} m", road=road.id, lane=lane.id, s=s, line=lane.line)


@rule("geometry.border-crossing", ERROR, tolerance=0.001, unit="m",
      summary="The outer border of a lane defined by <border> records never crosses its inner border "
              "(sampled every 0.25 m).",
      why="Crossing borders give a lane of negative width: overlapping surfaces and lanes that cannot be driven.")
def border_crossing(ctx, rule):
    arrays = ctx.odr.arrays
    if not np.any(arrays.lane_uses_border):
        return
    from tavf_mapkit.opendrive.sampling import sample_lanes

    sampling = sample_lanes(ctx.odr, step=0.25)
    border_pairs = arrays.lane_uses_border[sampling.pair_lane]
    signed_width = np.sign(sampling.lane_id) * (sampling.t_outer - sampling.t_inner)
    bad = np.flatnonzero(border_pairs & (signed_width < -rule.tolerance))
    rows = ctx.lane_rows
    reported = set()
    for k in bad:
        lane_row = int(sampling.pair_lane[k])
        if lane_row in reported:
            continue
        reported.add(lane_row)
        road, _, lane = rows[lane_row]
        yield Hit(f"outer border crosses the inner border by {-signed_width[k]:.4g} m", road=road.id, lane=lane.id,
                  s=float(sampling.s[k]), line=lane.line)


def _jumps(profile):
    """(index of the later record, jump) where a piecewise cubic is discontinuous between consecutive records."""
    if len(profile) < 2:
        return []
    c = profile.coefficients
    ds = np.diff(profile.s0)
    end_value = c[:-1, 0] + ds * (c[:-1, 1] + ds * (c[:-1, 2] + ds * c[:-1, 3]))
    jump = c[1:, 0] - end_value
    return [(i + 1, float(jump[i])) for i in range(len(jump)) if ds[i] > 0]


@rule("geometry.elevation-jump", WARNING, tolerance=0.01, unit="m",
      summary="Elevation is continuous along a road (consecutive elevation records meet).",
      why="A step in elevation is a step in the road surface: meshes tear and vehicles hit a wall.")
def elevation_jump(ctx, rule):
    for road in ctx.odr.roads:
        for index, jump in _jumps(road.elevation):
            if abs(jump) > rule.tolerance:
                s = float(road.elevation.s0[index])
                yield Hit(f"elevation jumps by {jump:+.4g} m", road=road.id, s=s, line=road.line)


@rule("geometry.border-jump", WARNING, tolerance=0.01, unit="m",
      summary="Lane offset and each lane's width are continuous inside a lane section (consecutive records meet).",
      why="A jump moves every lane border at once: the surface tears and lane-keeping sees a step.")
def border_jump(ctx, rule):
    for road in ctx.odr.roads:
        for index, jump in _jumps(road.lane_offset):
            if abs(jump) > rule.tolerance:
                yield Hit(f"lane offset jumps by {jump:+.4g} m", road=road.id, s=float(road.lane_offset.s0[index]),
                          line=road.line)
        for k, section in enumerate(road.lane_sections):
            end = road.section_end(k)
            for lane in section.side_lanes:
                profile = lane.borders if lane.uses_border else lane.widths
                for index, jump in _jumps(profile):
                    s = float(profile.s0[index])
                    if abs(jump) > rule.tolerance and s < end:
                        what = "border" if lane.uses_border else "width"
                        yield Hit(f"lane {what} jumps by {jump:+.4g} m", road=road.id, lane=lane.id, s=s,
                                  line=lane.line)


@rule("geometry.zero-length-road", ERROR,
      summary="Every road has a positive @length.",
      why="A zero-length road has no surface; links through it connect nothing and some readers divide by it.")
def zero_length_road(ctx, rule):
    for road in ctx.odr.roads:
        if not road.length > 0:
            yield Hit(f"road @length is {road.length:g}", road=road.id, line=road.line)


@rule("geometry.zero-length-geometry", WARNING,
      summary="Every planView geometry has a positive @length.",
      why="Zero-length geometries carry no road, yet their heading may contradict the neighbours; the schema "
          "requires lengths > 0.")
def zero_length_geometry(ctx, rule):
    table = ctx.odr.arrays.geometries
    for row in np.flatnonzero(~(table.length > 0) & np.isfinite(table.length)).tolist():
        road, geometry = _geometry_of_row(ctx.odr, table, row)
        yield Hit(f"geometry at s={geometry.s:g} has length 0", road=road.id, s=geometry.s, line=geometry.line)


@rule("geometry.plausible", ERROR,
      summary=f"Every planView vertex is a place on Earth (abs(x), abs(y) at most {COORDINATE_LIMIT:.0e} m, so not "
              f"SUMO's invalid-position sentinel -2^30 m), no road is longer than {WINDING:g} times the map's "
              f"extent (at least {MIN_ROAD_LIMIT / 1000:g} km), no lane width, border or lane offset reaches "
              f"{LATERAL_LIMIT:g} m and no elevation {ELEVATION_LIMIT / 1000:g} km.",
      why="Such numbers come from a writer that failed (netconvert's Position::INVALID) or from an edit. Everything "
          "downstream samples roads by length, so one of them is a terabyte allocation: mapkit refuses to sample "
          "such a road, and its build repairs or drops it.")
def plausible(ctx, rule):
    budget = ctx.odr.arrays.budget
    for road_index in sorted(budget.problems):
        line, _element, message = budget.problems[road_index]
        yield Hit(message, road=budget.road_ids[road_index], line=line)
