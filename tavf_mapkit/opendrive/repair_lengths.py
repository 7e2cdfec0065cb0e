"""Repair @length: every geometry as long as its curve, and everything along s moved with it.

s is the distance along the reference line, so a geometry's @length is its curve's arc length. netconvert
computes a paramPoly3's @length from the polyline it fitted the curve to, up to 24 cm short (DLR's TAVF
network; the validator's geometry.param-poly3-length). Read as the standard says (s = arc length; CARLA and
libOpenDRIVE do so too), such a road stops short of its curve's end: a gap before the next geometry or road.

netconvert's own s along such a curve -- of lane sections, widths, road marks, objects and signals -- is the
polyline's length, which grows in proportion to the curve's; so does the reading of this toolkit before it
read s as arc length, on which builds, meshes and drives were made. The repair keeps that placement: the
geometry's @length becomes its true arc length (``param_poly3_length``, exact to double precision), the s of
every later geometry and of every record of the road is mapped old s -> new s, stretched by arc length /
@length inside the repaired geometry and shifted after it, and cubic records (laneOffset, width, border,
elevation, superelevation) are re-expanded exactly in the new s -- split where the stretch changes inside
them, unless they are constant there. Every lane border therefore lies where that reading put it, and each
road ends exactly where its curve does. A file whose lengths are right is returned unchanged (idempotent).

Only a paramPoly3 can be off: a line, arc or spiral is defined by its length, and a poly3's u runs as far as
its arc length says. A road whose geometries are not in s order is left alone (structure.s-order).
"""

from __future__ import annotations

import math
from bisect import bisect_right
from dataclasses import dataclass, replace

import numpy as np

from tavf_mapkit.opendrive.cubic import CubicProfile
from tavf_mapkit.opendrive.geometry import (
    PARAMETER_NAMES,
    GeometryKind,
    join_rows,
    param_poly3_length,
    split_rows,
)
from tavf_mapkit.opendrive.refline import ReferenceLine, gather_side
from tavf_mapkit.opendrive.repair import Repair

#: Repair.action of this repair
GEOMETRY_LENGTH = "geometry length"

#: parameter slots a record of each kind has (by kind number)
_PARAMETER_SLOTS = np.array([len(PARAMETER_NAMES[kind]) for kind in sorted(PARAMETER_NAMES)])

#: an @length within this of the arc length is left as it is (netconvert writes 8 decimals: 1e-8 m)
TOLERANCE = 1e-6
#: roads whose reference lines are stretched in one pass (and share one new table of rows)
ROADS_PER_BATCH = 8192


def true_lengths(table) -> np.ndarray:
    """Arc length of every row of a GeometryTable: @length, except for a paramPoly3 its curve's true length."""
    lengths = table.length.copy()
    rows = np.flatnonzero(table.kind == int(GeometryKind.PARAM_POLY3))
    if len(rows):
        params = table.params[rows]
        p_end = np.where(params[:, 8] > 0.5, 1.0, table.length[rows])
        lengths[rows] = param_poly3_length(params, p_end)
    return lengths


def repair_geometry_lengths(odr, tolerance: float = TOLERANCE):
    """(repaired map, repairs): one Repair per road whose geometries' @length was not their arc length."""
    from tavf_mapkit.opendrive.network import OpenDriveMap

    table = odr.arrays.geometries
    if not len(table):
        return odr, []
    arc = true_lengths(table)
    # a zero-length geometry is never evaluated (the next one governs its s): not a length to repair here
    wrong = (np.abs(arc - table.length) > tolerance) & (table.length > 0)
    if not wrong.any():
        return odr, []
    # a road whose geometries are not in s order is left alone (structure.s-order)
    unordered = np.zeros(len(odr.roads), dtype=bool)
    if len(table) > 1:
        same = table.group[1:] == table.group[:-1]
        unordered[table.group[1:][same & (np.diff(table.s) < 0)]] = True
    indices = [index for index in np.unique(table.group[wrong]).tolist() if not unordered[index]]
    starts = np.searchsorted(table.group, np.arange(len(odr.roads)), side="left")
    roads, repairs = list(odr.roads), []
    stretched = (made for first in range(0, len(indices), ROADS_PER_BATCH)  # memory bounded by the batch
                 for made in _stretched_lines([roads[index] for index in indices[first:first + ROADS_PER_BATCH]],
                                              starts[indices[first:first + ROADS_PER_BATCH]], arc, wrong))
    for index, (mapping, line, changed, first_wrong) in zip(indices, stretched):
        road = roads[index]
        roads[index] = _stretched(road, mapping, line)
        first_line = int(road.reference_line.lines[first_wrong])
        repairs.append(Repair(
            GEOMETRY_LENGTH, road.id, None if first_line < 0 else first_line,
            f"{len(changed)} paramPoly3 @length set to the curve's arc length (by {_signed(changed)} m); "
            f"road @length {road.length:.9g} -> {roads[index].length:.9g} m"))
    if not repairs:
        return odr, []
    return OpenDriveMap(odr.header, tuple(roads), odr.junctions, odr.controllers, odr.source, odr.warnings,
                        odr.extra_xml), repairs


def _signed(changes: np.ndarray) -> str:
    worst = changes[np.argmax(np.abs(changes))]
    return f"{worst:+.4g}" if len(changes) == 1 else f"up to {worst:+.4g}"


@dataclass(frozen=True)
class SMap:
    """old s -> new s: piecewise linear through breakpoints ``old[i] -> new[i]`` with ``slope[i]`` on
    [old[i], old[i+1]); slope 1 before the first and after the last breakpoint. Where the slope is 1 the map is
    a shift, computed as s + (new - old) so that s not moved at all stays bit for bit what it was.

    Plain Python floats: a road has a few breakpoints and records, and scalar numpy calls cost more."""

    old: tuple[float, ...]
    new: tuple[float, ...]
    slope: tuple[float, ...]  # len(old) - 1

    def slope_after(self, s: float) -> float:
        """Slope of the map just after s."""
        k = bisect_right(self.old, s) - 1
        return self.slope[k] if 0 <= k < len(self.slope) else 1.0

    @property
    def fixed(self) -> float:
        """An s up to which (inclusive) the map leaves every s as it is (``at(s) == s``): where the first
        breakpoint whose slope is not 1, or whose new s is not its old one, is (the road's first stretched
        geometry). Whatever lies there or before is not moved, and need not be asked."""
        old, new, slope = self.old, self.new, self.slope
        if not all(math.isfinite(rate) for rate in slope):  # at(old[j]) would be new[j] + 0 * inf
            return -math.inf
        j = 0
        while j < len(slope) and slope[j] == 1.0 and new[j] == old[j]:
            j += 1
        if new[j] != old[j]:  # a shift (rounding after a gap) or NaN: not worth a closer look
            return -math.inf
        return math.inf if j == len(slope) else old[j]

    def at(self, s: float) -> float:
        s = float(s)
        k = bisect_right(self.old, s) - 1
        if k < 0:
            start, target, rate = self.old[0], self.new[0], 1.0
        else:
            start, target = self.old[k], self.new[k]
            rate = self.slope[k] if k < len(self.slope) else 1.0
        return float(s + (target - start) if rate == 1.0 else target + (s - start) * rate)

    def __call__(self, s) -> np.ndarray:
        return np.array([self.at(value) for value in np.ravel(s)]).reshape(np.shape(s))

    def cuts(self, a: float, b: float) -> list[float]:
        """Breakpoints strictly inside (a, b) where the slope changes."""
        found = []
        for k in range(bisect_right(self.old, a), len(self.old)):
            if self.old[k] >= b:
                break
            before = self.slope[k - 1] if 0 < k <= len(self.slope) else 1.0
            after = self.slope[k] if k < len(self.slope) else 1.0
            if before != after:
                found.append(self.old[k])
        return found


def _stretch_map(starts: list[float], lengths: list[float], arc: np.ndarray, wrong: np.ndarray) -> SMap:
    """The map of a road whose geometries (``starts``, @``lengths``) ``wrong`` get their arc length ``arc``: each
    geometry's old range [s, s + @length] (up to the next geometry's start) stretches by arc / @length; any s
    between the end of a geometry and the next start (a file whose s do not follow from the lengths) only
    shifts."""
    old, new, slope = [float(starts[0])], [float(starts[0])], []
    for k, (start, length) in enumerate(zip(starts, lengths)):
        start_old, start_new = old[-1], new[-1]
        following = starts[k + 1] if k + 1 < len(starts) else np.inf
        used = float(min(length, following - start))
        rate = float(arc[k] / length) if wrong[k] else 1.0
        old.append(start_old + used)
        new.append(start_new + used * rate)
        slope.append(rate)
        if np.isfinite(following) and following > old[-1]:
            old.append(following)
            new.append(new[-1] + following - old[-2])
            slope.append(1.0)
    return SMap(tuple(old), tuple(new), tuple(slope))


def _stretched_lines(roads: list, first_rows: np.ndarray, arc: np.ndarray, wrong: np.ndarray) -> list:
    """Per road (``first_rows``: where its rows start in the map's table, whose rows ``arc`` and ``wrong`` are):
    (its stretch map, its reference line with every wrong @length set to the arc length, the @length changes,
    the index of its first wrong geometry). The rows of all roads are changed in one pass, and the lines are views
    of one new table: a region's 57,000 stretched roads spent a third of the repair making them road by road."""
    if not roads:
        return []
    lines_of = [road.reference_line for road in roads]
    counts = np.array([len(line) for line in lines_of], dtype=np.int64)
    bounds = np.concatenate([[0], np.cumsum(counts)])
    rows = join_rows(np.concatenate([line.narrow for line in lines_of]), *gather_side(lines_of, counts))
    table_row = np.arange(len(rows)) + np.repeat(np.asarray(first_rows, dtype=np.int64) - bounds[:-1], counts)
    arc, wrong = arc[table_row], wrong[table_row]
    change = arc - rows[:, 4]
    starts, lengths, arcs, wrongs = rows[:, 0].tolist(), rows[:, 4].tolist(), arc.tolist(), wrong.tolist()
    mappings, new_starts = [], []
    for lo, hi in zip(bounds[:-1].tolist(), bounds[1:].tolist()):  # plain floats: a road has a few rows
        mapping = _stretch_map(starts[lo:hi], lengths[lo:hi], arcs[lo:hi], wrongs[lo:hi])
        mappings.append(mapping)
        at = mapping.at
        new_starts += [at(start) for start in starts[lo:hi]]
    rows[:, 0] = new_starts
    # only a paramPoly3 is ever wrong (true_lengths); with pRange arcLength its p runs to @length
    rescaled = wrong & (rows[:, 14] < 0.5) & (rows[:, 4] > 0)
    if rescaled.any():
        rows[rescaled, 6:14] = _rescaled_arc_length_params(rows[rescaled, 6:14], rows[rescaled, 4] / arc[rescaled])
    rows[wrong, 4] = arc[wrong]
    # a record keeps the parameters of its kind only, as its Geometry value would (the other slots read 0)
    rows[:, 6:][np.arange(9) >= _PARAMETER_SLOTS[rows[:, 5].astype(np.int64)][:, None]] = 0.0
    narrow, side_index, side_params = split_rows(rows)
    del rows  # the full rows go before the roads' new lines are made
    side_bounds = np.searchsorted(side_index, bounds).tolist()
    source_lines = np.concatenate([line.lines for line in lines_of])
    source_lines = np.where(source_lines < 0, -1, source_lines)
    out = []
    for r, line in enumerate(lines_of):
        lo, hi, sa, sb = int(bounds[r]), int(bounds[r + 1]), side_bounds[r], side_bounds[r + 1]
        extra_xml = {k: fragments for k, fragments in (line.extra_xml or {}).items() if fragments} or None
        new_line = ReferenceLine.from_narrow(narrow[lo:hi], side_index[sa:sb] - lo, side_params[sa:sb],
                                            source_lines[lo:hi], extra_xml)
        road_wrong = wrong[lo:hi]
        out.append((mappings[r], new_line, change[lo:hi][road_wrong], int(np.argmax(road_wrong))))
    return out


def _stretched(road, mapping: SMap, line: ReferenceLine):
    """The road on its stretched reference line (``_stretched_lines``) with everything along s mapped by the
    stretch. What lies where the map moves nothing (``SMap.fixed``: on most roads everything but the line, which
    starts where the stretch does) is taken over as it is, without asking the map (equal to what it would say)."""
    at = mapping.at
    fixed = mapping.fixed
    length = at(road.length)

    def profile(p: CubicProfile, end: float) -> CubicProfile:
        return p if _unmoved_profile(p, end, fixed) else _mapped_profile(p, mapping, end)

    def unmoved(items, name: str = "s0") -> bool:
        return all(getattr(item, name) <= fixed for item in items)

    def moved(items, name: str = "s0") -> tuple:
        return items if unmoved(items, name) else tuple(_moved(item, name, at) for item in items)

    def lane(item, section_end: float):
        if (unmoved(item.road_marks, "s_offset") and unmoved(item.records) and unmoved(item.heights)
                and _unmoved_profile(item.widths, section_end, fixed)
                and _unmoved_profile(item.borders, section_end, fixed)):
            return item
        changes = {"widths": profile(item.widths, section_end), "borders": profile(item.borders, section_end),
                   "heights": moved(item.heights), "road_marks": moved(item.road_marks, "s_offset"),
                   "records": moved(item.records)}
        if all(value is getattr(item, key) or value == getattr(item, key) for key, value in changes.items()):
            return item  # most lanes start where the road does: nothing of them moves (and replace is slow)
        return replace(item, **changes)

    def section(k: int, item):
        lanes = tuple(lane(one, road.section_end(k)) for one in item.lanes)
        if item.s0 <= fixed and all(new is old for new, old in zip(lanes, item.lanes)):
            return item
        return _moved(item, "s0", at, lanes=lanes)

    sections = tuple(section(k, item) for k, item in enumerate(road.lane_sections))
    return replace(
        road, length=length, reference_line=line, lane_sections=sections,
        types=moved(road.types), elevation=profile(road.elevation, road.length),
        superelevation=profile(road.superelevation, road.length), lane_offset=profile(road.lane_offset, road.length),
        shape=moved(road.shape), objects=tuple(_mapped_object(o, at) for o in road.objects),
        signals=moved(road.signals, "s"), signal_references=moved(road.signal_references, "s"),
        attrib={**road.attrib, "length": repr(length)},
    )


def _unmoved_profile(p: CubicProfile, end: float, fixed: float) -> bool:
    """Whether ``_mapped_profile`` would give the profile back unchanged because the map moves nothing where it
    lies (up to ``fixed``): every record starts there, and is constant (re-expanded about its own start: the
    same numbers, whatever the slope) or ends there too (not cut; slope 1)."""
    if not len(p):
        return True
    s0 = p.s0.tolist()
    stops = [*s0[1:], float(max(end, s0[-1]))]
    for start, stop, (_, b, c, d) in zip(s0, stops, p.coefficients.tolist()):
        if not (start <= fixed and (b == c == d == 0.0 or (start < fixed and stop <= fixed))):
            return False
    return True


def _moved(item, name: str, at, **more):
    """``item`` with its s field ``name`` mapped (and ``more`` fields set); the very item if nothing changes."""
    value = getattr(item, name)
    new = at(value)
    if new == value and all(getattr(item, key) is v for key, v in more.items()):
        return item
    return replace(item, **{name: new}, **more)


def _rescaled_arc_length_params(params: np.ndarray, ratio: np.ndarray) -> np.ndarray:
    """paramPoly3 coefficients (rows of aU, bU, cU, dU, aV, bV, cV, dV) for p' = p / ratio: with pRange
    arcLength p runs to @length, so a new @length must not extend the curve; u(p) = u'(p') with b' = b ratio,
    c' = c ratio^2, d' = d ratio^3."""
    ratio = ratio[:, None]
    powers = np.hstack([np.ones_like(ratio), ratio, ratio * ratio, ratio * ratio * ratio])
    return params * np.hstack([powers, powers])


def _mapped_profile(p: CubicProfile, mapping: SMap, end: float) -> CubicProfile:
    """A cubic profile in the new s: each record, over [its s0, the next record's s0 or ``end``), is cut where
    the stretch changes (unless it is constant) and every piece re-expanded about its own start, so that the
    new profile at map(s) is the old one at s (exactly, up to rounding)."""
    if not len(p):
        return p
    # plain floats throughout: a road has a few records, and a region's lanes are hundreds of thousands
    s0, coefficients = p.s0.tolist(), p.coefficients.tolist()
    stops = [*s0[1:], float(max(end, s0[-1]))]
    new_s0, new_coefficients = [], []
    for start, stop, (a, b, c, d) in zip(s0, stops, coefficients):
        pieces = [start] if b == c == d == 0.0 else [start, *mapping.cuts(start, stop)]
        for origin in pieces:
            rate = mapping.slope_after(origin)
            x = origin - start  # the old polynomial's argument where the piece begins
            value = a + x * (b + x * (c + x * d))
            first = (b + x * (2.0 * c + 3.0 * d * x)) / rate
            second = (c + 3.0 * d * x) / rate ** 2
            third = d / rate ** 3
            new_s0.append(mapping.at(origin))
            new_coefficients.append((value, first, second, third))
    if new_s0 == s0 and new_coefficients == [tuple(record) for record in coefficients]:
        return p  # equal as np.array_equal has it (==, NaN never equal: every value here is newly computed)
    return replace(p, s0=np.array(new_s0), coefficients=np.array(new_coefficients, dtype=float).reshape(-1, 4))


def _mapped_object(o, at):
    """An object at its new s; a repeat keeps covering the same stretch of road (start and end mapped)."""

    def repeat(item):
        start, stop = at(item.s), at(item.s + item.length)
        attrib = dict(item.attrib)
        if "s" in attrib:
            attrib["s"] = repr(start)
        if "length" in attrib and stop - start != item.length:
            attrib["length"] = repr(stop - start)
        return replace(item, s=start, length=stop - start, attrib=attrib)

    def outline(item):
        corners = tuple(replace(c, a=at(c.a), attrib={**c.attrib, "s": repr(at(c.a))} if "s" in c.attrib
                                else c.attrib) if c.kind == "cornerRoad" else c for c in item.corners)
        return replace(item, corners=corners)

    return replace(o, s=at(o.s), repeats=tuple(repeat(r) for r in o.repeats),
                   outlines=tuple(outline(x) for x in o.outlines))
