"""Repair a map whose writer failed in places: drop impossible vertices, cut absurd lengths, drop what is left.

netconvert writes a planView vertex it could not compute as SUMO's invalid-position sentinel (-2^30, -2^30):
on Andorra a 0.8 m edge became a road of 3,036,999,778 m that runs to the sentinel and back. The reference
line of a road passes through anchors: the start of every geometry and the road's end. An anchor that is
off Earth (the sentinel), or far outside the extent of the input, is dropped and the geometries around it
become one straight line between the valid anchors on either side; s, the road's length and everything
positioned along s (lane sections, widths, marks, profiles, objects, signals) are mapped onto the new line.
A road left without two valid anchors, or whose lanes or elevation are absurd, is dropped with its links.
Every repair is reported (``Repair``) so the build can count and name it.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from tavf_mapkit.opendrive.cubic import CubicProfile
from tavf_mapkit.opendrive.geometry import Geometry, GeometryKind
from tavf_mapkit.opendrive.plausibility import Extent, off_earth, vertex_problem
from tavf_mapkit.opendrive.refline import ReferenceLine

#: actions of a Repair
DROPPED_VERTICES = "dropped vertices"
CUT_LENGTH = "cut length"
DROPPED_ROAD = "dropped road"


@dataclass(frozen=True, slots=True)  # slotted: a city's build makes 300,000 of them
class Repair:
    action: str  # DROPPED_VERTICES, CUT_LENGTH or DROPPED_ROAD
    road: str
    line: int | None
    detail: str

    def __str__(self) -> str:
        where = f"line {self.line}: " if self.line else ""
        who = f"road {self.road}: " if self.road else ""  # a repair of a controller or junction names no road
        return f"{where}{who}{self.detail}"


def outlying_margin(extent: Extent) -> float:
    """How far outside the input's extent a vertex may lie before it counts as broken (m)."""
    return max(1000.0, 0.1 * extent.diagonal)


def repair_untrusted_geometry(odr, extent: Extent | None = None):
    """(repaired map, repairs). ``extent``: the input's extent in the map's local coordinates, if known; a
    vertex more than ``outlying_margin`` outside it is treated like one off Earth."""
    arrays = odr.arrays
    table, budget = arrays.geometries, arrays.budget
    bad_vertex = off_earth(table.x, table.y)
    if extent is not None:
        bad_vertex |= extent.outside(table.x, table.y, outlying_margin(extent))
    # the road's end anchor: where its last geometry ends, over the part of it the road uses
    last = np.flatnonzero(np.r_[table.group[1:] != table.group[:-1], True]) if len(table) else np.zeros(0, int)
    used = np.minimum(table.length[last], np.maximum(arrays.road_length[table.group[last]] - table.s[last], 0.0))
    with np.errstate(all="ignore"):
        end_x, end_y, _, _ = table.evaluate(last, used)
    bad_end = off_earth(end_x, end_y)
    if extent is not None:
        bad_end |= extent.outside(end_x, end_y, outlying_margin(extent))
    suspects = set(budget.problems) | set(table.group[bad_vertex].tolist()) | set(table.group[last[bad_end]].tolist())
    if not suspects:
        return odr, []

    first_of = {int(group): int(k) for k, group in reversed(list(enumerate(table.group.tolist())))}
    end_of = {int(table.group[k]): (float(end_x[i]), float(end_y[i]), bool(bad_end[i]), float(used[i]))
              for i, k in enumerate(last.tolist())}
    roads, repairs, dropped = list(odr.roads), [], set()
    for index in sorted(suspects):
        road = roads[index]
        n = len(road.reference_line)
        start = first_of.get(index, 0)
        valid = np.r_[~bad_vertex[start:start + n], not end_of[index][2]] if n else np.zeros(0, bool)
        lateral = index in budget.problems and budget.problems[index][1] not in ("geometry", "road")
        if lateral or not n or np.count_nonzero(valid) < 2:
            reason = budget.problems[index][2] if index in budget.problems else _first_vertex_problem(road, valid)
            repairs.append(Repair(DROPPED_ROAD, road.id, road.line, f"dropped the road: {reason}"))
            dropped.add(road.id)
            continue
        rebuilt, repair = _reanchor(road, valid, end_of[index], budget.road_limit)
        if rebuilt is None:
            dropped.add(road.id)
        else:
            roads[index] = rebuilt
        repairs.append(repair)
    repaired = _without(odr, roads, dropped)
    # a road re-anchored for one problem may still have another (an absurd lane width): it goes too
    left = repaired.arrays.budget.problems
    if left:
        for index, (line, _element, message) in sorted(left.items()):
            road = repaired.roads[index]
            repairs.append(Repair(DROPPED_ROAD, road.id, line, f"dropped the road: {message}"))
            dropped.add(road.id)
        repaired = _without(odr, [road for road in repaired.roads], dropped)
    return repaired, repairs


def _without(odr, roads, dropped: set[str]):
    """The map with ``roads`` (repaired ones in place) less the dropped ones and every link to them."""
    from tavf_mapkit.opendrive.network import OpenDriveMap

    junctions, controllers = odr.junctions, odr.controllers
    if dropped:
        roads = [road for road in roads if road.id not in dropped]
        roads, junctions, controllers = _unlink(roads, junctions, controllers, dropped, odr.roads)
    return OpenDriveMap(odr.header, tuple(roads), tuple(junctions), tuple(controllers), odr.source, odr.warnings,
                        odr.extra_xml)


def _first_vertex_problem(road, valid) -> str:
    """Why a road has fewer than two trusted anchors (its first untrusted geometry start)."""
    for k, geometry in enumerate(road.reference_line.geometries):
        if not valid[k]:
            problem = vertex_problem(geometry.x, geometry.y)
            return problem or f"x={geometry.x:.6g}, y={geometry.y:.6g} lies far outside the input's extent"
    return "its reference line has fewer than two vertices that can be trusted"


def _reanchor(road, valid: np.ndarray, end, road_limit: float):
    """The road through its valid anchors only (straight lines where anchors were dropped), or None."""
    geometries = road.reference_line.geometries
    n = len(geometries)
    end_x, end_y, _, used = end
    anchor_xy = [(g.x, g.y) for g in geometries] + [(end_x, end_y)]
    anchor_s = [g.s for g in geometries] + [geometries[-1].s + used]
    keep = np.flatnonzero(valid).tolist()
    new, old_s, new_s = [], [anchor_s[keep[0]]], [0.0]
    for a, b in zip(keep, keep[1:]):
        s = new_s[-1]
        if b == a + 1:  # both ends trusted: the geometry stays as it is
            new.append(replace(geometries[a], s=s))
            length = geometries[a].length if b < n else used
        else:
            (xa, ya), (xb, yb) = anchor_xy[a], anchor_xy[b]
            length = float(np.hypot(xb - xa, yb - ya))
            new.append(Geometry(s, xa, ya, float(np.arctan2(yb - ya, xb - xa)), length, GeometryKind.LINE, (),
                                geometries[a].line))
        old_s.append(anchor_s[b])
        new_s.append(s + length)
    length = new_s[-1]
    if not length > 0:
        return None, Repair(DROPPED_ROAD, road.id, road.line, "dropped the road: nothing of it is left between "
                                                             "the vertices that can be trusted")
    invalid = np.flatnonzero(~valid)
    if len(invalid):
        first = int(invalid[0])
        x, y = anchor_xy[first]
        problem = vertex_problem(x, y) or f"x={x:.6g}, y={y:.6g} lies far outside the input's extent"
        detail = (f"dropped {len(invalid)} of {n + 1} reference-line vertices ({problem}); "
                  f"@length {road.length:.6g} -> {length:.6g} m")
        action, line = DROPPED_VERTICES, geometries[first].line if first < n else road.line
    else:
        if not length <= road_limit:
            return None, Repair(DROPPED_ROAD, road.id, road.line,
                                f"dropped the road: its geometry is {length:.6g} m long as well as its @length")
        detail = f"@length {road.length:.6g} m cut to {length:.6g} m, where its geometry ends"
        action, line = CUT_LENGTH, road.line
    return _moved_along_s(road, new, np.array(old_s), np.array(new_s)), Repair(action, road.id, line, detail)


def _moved_along_s(road, geometries: list[Geometry], old_s: np.ndarray, new_s: np.ndarray):
    """The road with a new reference line; everything positioned along s is mapped old s -> new s
    (piecewise linear through the anchors, clamped to the new road)."""

    def at(s):
        return float(np.interp(s, old_s, new_s))

    def profile(p: CubicProfile) -> CubicProfile:
        return replace(p, s0=np.interp(p.s0, old_s, new_s)) if len(p) else p

    def lane(item):
        return replace(item, widths=profile(item.widths), borders=profile(item.borders),
                       heights=tuple(replace(h, s0=at(h.s0)) for h in item.heights),
                       road_marks=tuple(replace(m, s_offset=at(m.s_offset)) for m in item.road_marks),
                       records=tuple(replace(r, s0=at(r.s0)) for r in item.records))

    def repeat(item):
        return replace(item, s=at(item.s), attrib={**item.attrib, "s": repr(at(item.s))} if "s" in item.attrib
                       else item.attrib)

    sections = tuple(replace(section, s0=at(section.s0), lanes=tuple(lane(item) for item in section.lanes))
                     for section in road.lane_sections)
    return replace(
        road, length=float(new_s[-1]), reference_line=ReferenceLine(tuple(geometries)), lane_sections=sections,
        types=tuple(replace(t, s0=at(t.s0)) for t in road.types),
        elevation=profile(road.elevation), superelevation=profile(road.superelevation),
        lane_offset=profile(road.lane_offset), shape=tuple(replace(x, s0=at(x.s0)) for x in road.shape),
        objects=tuple(replace(o, s=at(o.s), repeats=tuple(repeat(r) for r in o.repeats)) for o in road.objects),
        signals=tuple(replace(x, s=at(x.s)) for x in road.signals),
        signal_references=tuple(replace(x, s=at(x.s)) for x in road.signal_references),
        attrib={**road.attrib, "length": repr(float(new_s[-1]))},
    )


def _unlink(roads, junctions, controllers, dropped: set[str], original):
    """Remove every link to a dropped road: road and lane links, junction connections, signal controls."""

    def cut(road):
        changes = {}
        sections = list(road.lane_sections)
        for name, index, lane_field in (("predecessor", 0, "predecessor"), ("successor", -1, "successor")):
            link = getattr(road, name)
            if link is not None and link.element_type == "road" and link.element_id in dropped:
                changes[name] = None
                if sections:
                    sections[index] = replace(sections[index], lanes=tuple(
                        replace(lane, **{lane_field: None}) for lane in sections[index].lanes))
        if changes:
            changes["lane_sections"] = tuple(sections)
            return replace(road, **changes)
        return road

    roads = [cut(road) for road in roads]
    junctions = [replace(j, connections=tuple(c for c in j.connections
                                              if c.incoming_road not in dropped and c.connecting_road not in dropped))
                 for j in junctions]
    gone_signals = {signal.id for road in original if road.id in dropped for signal in road.signals}
    if gone_signals:
        controllers = [replace(c, signal_ids=tuple(i for i in c.signal_ids if i not in gone_signals))
                       for c in controllers]
    return roads, junctions, controllers
