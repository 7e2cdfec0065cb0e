"""Make a junction's connecting roads meet the lanes they link: netconvert's contact gaps, closed.

Why netconvert's connecting roads miss their neighbours (SUMO netconvert 1.28, NWWriter_OpenDrive):
- **Turnarounds.** A U-turn's reference line is a quadratic Bezier whose middle control point lies a chord's
  length beyond the chord's midpoint: it leaves the incoming lane atan(1/2) = 26.57 degrees off its heading,
  and since a lane's cross-section is normal to its own reference line, the lane's far border misses by
  2 w sin(13.3 deg) (1.4-2.8 m for 3-6 m lanes). In a left-hand network the Bezier is mirrored (153.4 degrees
  off, the far border 2 w away).
- **Stub connecting roads.** Where SUMO's junction has no area (two edges meeting at a point), the connecting
  road is a straight line between two points millimetres apart: its heading is noise (up to 180 degrees off),
  so every lane but the one at the reference line lands metres away; its @length is floored to 0.1 m while
  the line is shorter (``geometry.length``).
- **Straight fallbacks.** When netconvert cannot compute a smooth shape ("Could not compute smooth shape ...")
  it writes a straight line between the lane ends, whatever their headings.
- **Merges.** netconvert writes parallel connections from one road to another as one road with parallel lanes
  of constant width, also when two of them end on the same lane: one of the two cannot meet it.
- **Width rounding.** A connecting lane's width is ``a + b s`` with b written to two decimals (netconvert's
  default --precision): up to 7 cm off at the end of a 13 m road. --precision would cure it at the source but
  also rounds every node of the network differently (roads move by millimetres, and at 3 digits or more Berlin's
  build gains two 1.5 mm geometry gaps), so the widths are refitted here instead.

The repair, per connecting road (in a junction, one lane section, lanes on one side, road links at both ends)
whose lanes miss the lanes they link by more than TOLERANCE or HEADING_TOLERANCE, whose @length is not its
geometry's, or whose reference line reverses on itself (a paramPoly3 with a cusp: netconvert draws a few junction
curves as loops, e.g. London road 9919, which no lane follows and no chain of arcs can replace):
- lanes are grouped so that each group's targets are adjacent lanes of the neighbours; a road whose lanes need
  two groups (a merge) is split, the extra group becoming a new connecting road with its own junction
  connection;
- where only the widths are off, the widths become cubics from the incoming to the outgoing lane widths;
- otherwise the reference line is rebuilt as one paramPoly3 from the neighbour's lane border to the other's with
  their headings (connecting_curve.py), on the border on the outside of the turn (so a U-turn that pivots about
  the street's middle has a regular reference line); widths are cubics with level ends, the lane offset their
  sum where the reference line is the outer border, the elevation a cubic continuing both neighbours' grades;
  everything else along s (marks, speeds, objects, signals) is scaled to the new length;
- where no sensible curve exists (the lanes lie behind one another, or face apart), the link is dropped: the
  road and its junction connection go, and a junction left without connections goes with the road links to it.
Every change is a ``Repair`` the build counts and names. Repairing a repaired map changes nothing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from itertools import pairwise

import numpy as np

from tavf_mapkit.opendrive.connecting_curve import (
    ConnectingCurve,
    cubic_record,
    hermite_curve,
    hermite_profile,
    reverses,
    smooth_step,
    wrap,
)
from tavf_mapkit.opendrive.cubic import EMPTY_PROFILE
from tavf_mapkit.opendrive.geometry import GeometryKind
from tavf_mapkit.opendrive.junction import Connection, LaneLink
from tavf_mapkit.opendrive.refline import ReferenceLine
from tavf_mapkit.opendrive.repair import Repair

#: lane borders this close (m) to the borders they link meet; headings this close (rad) continue each other
TOLERANCE = 1e-3
HEADING_TOLERANCE = math.radians(0.1)

#: actions of a Repair
REBUILT_CONNECTING_ROAD = "rebuilt connecting road"
REFITTED_LANE_WIDTHS = "refitted connecting lane widths"
SPLIT_CONNECTING_ROAD = "split connecting road"
DROPPED_LINK = "dropped link"
DROPPED_JUNCTION = "dropped empty junction"


@dataclass(frozen=True)
class End:
    """What one end of a connecting road must meet: heading of travel there, and per lane of the connecting
    road the xy of the inner and outer border of the lane it links to."""

    road: object  # the neighbour Road
    contact: str  # the neighbour's end: "start" or "end"
    heading: float  # along the connecting road's s
    z: float
    grade: float  # dz/ds along the connecting road's s
    inner: dict  # connecting lane id -> (2,) xy
    outer: dict


@dataclass(frozen=True)
class RoadEnd:
    """A road's reference frame and lane borders at its start or end, as the validator samples them."""

    xy: np.ndarray  # reference point
    heading: float
    z: float
    grade: float
    lateral: np.ndarray  # xy of the unit vector of t (the surface normal, superelevation included)
    lane_offset: float
    borders: dict  # lane id -> (inner xy, outer xy)


class EndTable:
    """(road id, "start" | "end") -> RoadEnd, made on demand from arrays of the samples at every road's ends.

    Not a dict of RoadEnds: on a city (Columbus: 155,000 roads) a RoadEnd per road end, each with its own small
    arrays and a dict of border points per lane, took 600 MB at once; the arrays they are made of take 30 MB.
    Lookups give the same values as the RoadEnds would have held (a road id that occurs twice: its last road)."""

    def __init__(self, index: dict, xy, heading, z, grade, lateral, lane_offset, pair_start, lane_id, inner, outer):
        self._index = index  # road id -> k: its start is sample 2k, its end 2k + 1
        self._xy, self._heading, self._z, self._grade = xy, heading, z, grade
        self._lateral, self._lane_offset = lateral, lane_offset
        self._pair_start = pair_start  # sample -> its first pair in (lane_id, inner, outer); pairs by sample
        self._lane_id, self._inner, self._outer = lane_id, inner, outer

    def _sample(self, key) -> int | None:
        road_id, end = key
        k = self._index.get(road_id)
        if k is None or end not in ("start", "end"):
            return None
        return 2 * k + (end == "end")

    def __contains__(self, key) -> bool:
        return self._sample(key) is not None

    def __getitem__(self, key) -> RoadEnd:
        k = self._sample(key)
        if k is None:
            raise KeyError(key)
        lo, hi = int(self._pair_start[k]), int(self._pair_start[k + 1])
        borders = {lane: (self._inner[j], self._outer[j])
                   for j, lane in zip(range(lo, hi), self._lane_id[lo:hi].tolist())}
        return RoadEnd(self._xy[k].copy(), float(self._heading[k]), float(self._z[k]), float(self._grade[k]),
                       self._lateral[k], float(self._lane_offset[k]), borders)


def end_table(odr) -> EndTable:
    """(road id, "start" | "end") -> RoadEnd for every road with lanes, in one vectorised pass: the first lane
    section at s = 0 and the last at the road's length."""
    from tavf_mapkit.opendrive.sampling import sample_lanes_at

    arrays = odr.arrays
    section_road = arrays.section_road
    if not len(section_road):
        return EndTable({}, *(np.zeros(0),) * 6, np.zeros(1, dtype=np.int64), *(np.zeros(0),) * 3)
    roads = np.unique(section_road)
    first = np.searchsorted(section_road, roads, side="left")
    last = np.searchsorted(section_road, roads, side="right") - 1
    lengths = np.array([odr.roads[r].length for r in roads], dtype=float)
    sections = np.column_stack([first, last]).ravel()  # grouped by section: a road's sections ascend
    s = np.column_stack([np.zeros(len(roads)), lengths]).ravel()
    sampling = sample_lanes_at(odr, sections, s)
    lateral = np.ascontiguousarray(sampling._frame[0][:, :2])
    by_sample = np.argsort(sampling.pair_sample, kind="stable")  # pairs come lane by lane: regroup by sample
    inner = sampling.points_at(sampling.t_inner)[by_sample, :2]
    outer = sampling.points_at(sampling.t_outer)[by_sample, :2]
    pair_start = np.searchsorted(sampling.pair_sample[by_sample], np.arange(len(s) + 1))
    index = {odr.roads[road].id: k for k, road in enumerate(roads.tolist())}
    return EndTable(index, np.column_stack([sampling.ref_x, sampling.ref_y]), sampling.heading, sampling.ref_z,
                    sampling.slope, lateral, sampling.lane_offset, pair_start, sampling.lane_id[by_sample],
                    inner, outer)


def repair_contacts(odr):
    """(repaired map, repairs)."""
    from tavf_mapkit.opendrive.network import OpenDriveMap
    from tavf_mapkit.opendrive.repair import _without

    roads_by_id = odr.road_by_id
    table = end_table(odr)
    next_road = _next_id(road.id for road in odr.roads)
    reversing = _reversing_roads(odr)
    roads, repairs, dropped = [], [], set()
    # connecting road id -> [(new road, {old lane id: new lane id})] that replace it in its junction
    replaced: dict = {}
    for index, road in enumerate(odr.roads):
        ends = _ends(road, roads_by_id, table)
        if ends is None:
            roads.append(road)
            continue
        outcome = _repair_road(road, ends, next_road, table, index in reversing)
        if outcome is None:
            roads.append(road)
            continue
        new_roads, road_repairs = outcome
        repairs += road_repairs
        next_road += max(0, len(new_roads) - 1)
        roads += [new for new, _ in new_roads]
        if not new_roads:
            dropped.add(road.id)
        replaced[road.id] = new_roads
    if not repairs:
        return odr, []
    junctions, gone = [], set()
    for junction in odr.junctions:
        connections = _connections(junction, replaced)
        if connections or not junction.connections:
            junctions.append(replace(junction, connections=tuple(connections)))
        else:
            gone.add(junction.id)
            repairs.append(Repair(DROPPED_JUNCTION, "", junction.line,
                                  f"dropped junction {junction.id}: no connection is left in it"))
    if gone:
        roads = [_unlink_junctions(road, gone) for road in roads]
    repaired = OpenDriveMap(odr.header, tuple(roads), tuple(junctions), odr.controllers, odr.source, odr.warnings,
                            odr.extra_xml)
    if dropped:
        repaired = _without(repaired, list(repaired.roads), dropped)
    return repaired, repairs


#: paramPoly3 rows checked for a cusp at once (samples per row: connecting_curve._CUSP_SAMPLES)
_ROWS_PER_BATCH = 4096


def _reversing_roads(odr) -> set:
    """Indices of the connecting roads whose reference line has a paramPoly3 that reverses on itself (netconvert
    draws some junction curves as loops with a cusp): such a road is rebuilt like one that misses its
    neighbours, since no lane follows it and no chain of arcs can replace it. Only roads in a junction are
    asked (the others' curves, most of a map's, are never judged here)."""
    table = odr.arrays.geometries
    in_junction = np.array([road.in_junction for road in odr.roads], dtype=bool)
    rows = np.flatnonzero((table.kind == int(GeometryKind.PARAM_POLY3)) & (table.length > 0)
                          & in_junction[table.group])
    found = []
    for first in range(0, len(rows), _ROWS_PER_BATCH):
        batch = rows[first:first + _ROWS_PER_BATCH]
        params = table.params[batch]
        p_end = np.where(params[:, 8] > 0.5, 1.0, table.length[batch])
        found.append(table.group[batch][reverses(params, p_end)])
    return set(np.concatenate(found).tolist()) if found else set()


def _next_id(ids) -> int:
    """One above the largest integer road id (netconvert's ids are integers)."""
    numbers = [int(i) for i in ids if str(i).lstrip("-").isdigit()]
    return max(numbers, default=0) + 1


def _ends(road, roads_by_id, table):
    """(start End, end End) of a connecting road this repair can judge, or None."""
    if not road.in_junction or len(road.lane_sections) != 1 or not len(road.reference_line):
        return None
    lanes = road.lane_sections[0].side_lanes
    if not lanes or len({lane.side for lane in lanes}) != 1 or (road.id, "start") not in table:
        return None
    ends = []
    for link, at_start in ((road.predecessor, True), (road.successor, False)):
        if link is None or link.element_type != "road" or link.element_id not in roads_by_id:
            return None
        other = roads_by_id[link.element_id]
        if other.in_junction or link.contact_point not in ("start", "end") or (other.id, "start") not in table:
            return None
        end = _end(road, other, table[(other.id, link.contact_point)], link.contact_point, at_start)
        if end is None:
            return None
        ends.append(end)
    return tuple(ends)


def _end(road, other, there, contact: str, at_start: bool):
    """The End a connecting road's start (``at_start``) or end meets at ``other``'s ``contact`` (``there``)."""
    # travel along the connecting road leaves a road's end / enters a road's start in the road's direction
    forward = (contact == "end") == at_start
    inner, outer = {}, {}
    for lane in road.lane_sections[0].side_lanes:
        target = lane.predecessor if at_start else lane.successor
        if target is None or target == 0 or target not in there.borders:
            return None
        inner[lane.id], outer[lane.id] = there.borders[target]
    return End(other, contact, there.heading + (0.0 if forward else math.pi), there.z,
               there.grade * (1.0 if forward else -1.0), inner, outer)


def _groups(road, ends) -> list[list]:
    """The road's lanes (from the reference line outwards) in runs whose targets are adjacent lanes at both
    ends: each run can be one road."""
    lanes = sorted(road.lane_sections[0].side_lanes, key=lambda lane: abs(lane.id))
    groups = [[lanes[0]]]
    for before, lane in pairwise(lanes):
        adjacent = all(np.hypot(*(end.outer[before.id] - end.inner[lane.id])) <= TOLERANCE for end in ends)
        if adjacent:
            groups[-1].append(lane)
        else:
            groups.append([lane])
    return groups


def _misfit(road, ends, table, widths=None) -> tuple[float, float]:
    """(largest border distance in m, largest heading break in rad) of the road's lanes against their targets;
    ``widths``: lane id -> (width at the start, width at the end) in place of the lanes' own."""
    distance, heading_break = 0.0, 0.0
    lanes = sorted(road.lane_sections[0].side_lanes, key=lambda lane: abs(lane.id))
    for k, (here, end) in enumerate(((table[(road.id, "start")], ends[0]), (table[(road.id, "end")], ends[1]))):
        heading_break = max(heading_break, abs(float(wrap(here.heading - end.heading))))
        t = here.lane_offset
        points, targets = [], []
        for lane in lanes:
            if widths is None:
                inner, outer = here.borders[lane.id]
            else:
                inner = here.xy + t * here.lateral
                t += lane.side * widths[lane.id][k]
                outer = here.xy + t * here.lateral
            points += (inner, outer)
            targets += (end.inner[lane.id], end.outer[lane.id])
        # every border's distance in one call (a road's few lanes: numpy's overhead is per call), the largest
        # taken in the same order as one by one
        if points:
            gaps = np.subtract(points, targets)
            distance = max(distance, *np.hypot(gaps[:, 0], gaps[:, 1]).tolist())
    return distance, heading_break


def _length_consistent(road) -> bool:
    rows = road.reference_line.narrow  # s and @length of each record (no Geometry values made)
    starts, lengths = rows[:, 0].tolist(), rows[:, 4].tolist()
    if abs(starts[0]) > TOLERANCE:
        return False
    for k in range(len(starts) - 1):
        if abs(starts[k + 1] - starts[k] - lengths[k]) > TOLERANCE:
            return False
    return abs(starts[-1] + lengths[-1] - road.length) <= TOLERANCE


def _width(end, lane_id) -> float:
    return float(np.hypot(*(end.outer[lane_id] - end.inner[lane_id])))


def _repair_road(road, ends, next_road: int, table, reversing: bool = False):
    """([(road that replaces it, {old lane id: new lane id})], repairs), or None when it meets its neighbours
    already (and its reference line does not reverse, ``reversing``). No roads: the link was dropped."""
    start, end = ends
    groups = _groups(road, ends)
    consistent = _length_consistent(road)
    distance, heading_break = _misfit(road, ends, table)
    meets = distance <= TOLERANCE and heading_break <= HEADING_TOLERANCE
    if len(groups) == 1 and consistent and meets and not reversing:
        return None
    where = f"between road {start.road.id} and road {end.road.id}"
    if not meets:
        problem = (f"its lanes were up to {distance:.3g} m from the lanes they link, headings "
                   f"{math.degrees(heading_break):.3g} deg apart")
    elif reversing:
        problem = "its reference line reversed on itself (a cusp)"
    else:
        problem = f"@length {road.length:.6g} m is not its geometry's"
    if len(groups) == 1 and consistent and not reversing:
        length = float(road.length)
        targets = {lane.id: (_width(start, lane.id), _width(end, lane.id)) for lane in groups[0]}
        refitted, refitted_break = _misfit(road, ends, table, targets)
        if refitted <= TOLERANCE and refitted_break <= HEADING_TOLERANCE:
            widths = {lane.id: cubic_record(smooth_step(*targets[lane.id], length)) for lane in groups[0]}
            lanes = tuple(replace(lane, widths=widths[lane.id], borders=EMPTY_PROFILE) if lane.id in widths
                          else lane for lane in road.lane_sections[0].lanes)
            new = replace(road, lane_sections=(replace(road.lane_sections[0], lanes=lanes),))
            identity = {lane.id: lane.id for lane in groups[0]}
            return [(new, identity)], [Repair(REFITTED_LANE_WIDTHS, road.id, road.line,
                                                      f"{where}: {problem}; widths now run from theirs to theirs")]
    new_roads, repairs = [], []
    for k, group in enumerate(groups):
        ids = [lane.id for lane in group]
        curve, rebuilt = _rebuilt(road, ends, group)
        if curve.problem is not None:
            repairs.append(Repair(DROPPED_LINK, road.id, road.line,
                                  f"dropped the link {where} through lanes {_lanes(ids)} (road and junction "
                                  f"connection): no sensible connecting road, {curve.problem}"))
            continue
        road_id = road.id if not new_roads else str(next_road + len(new_roads) - 1)
        side = group[0].side
        mapping = {lane.id: side * (i + 1) for i, lane in enumerate(group)}
        rebuilt = _renumbered(replace(rebuilt, id=road_id), mapping)
        new_roads.append((rebuilt, mapping))
        if road_id == road.id:
            repairs.append(Repair(REBUILT_CONNECTING_ROAD, road.id, road.line,
                                  f"{where}: {problem}; new reference line (paramPoly3 of {curve.length:.4g} m) "
                                  f"from lane border to lane border"))
        else:
            repairs.append(Repair(SPLIT_CONNECTING_ROAD, road.id, road.line,
                                  f"lanes {_lanes(ids)} of the road {where} are new connecting road {road_id}: "
                                  f"their lanes are not beside those of lanes {_lanes([g.id for g in groups[0]])}"
                                  f" at both ends (lanes merging or splitting)"))
    return new_roads, repairs


def _lanes(ids) -> str:
    return ", ".join(str(i) for i in ids)


def _rebuilt(road, ends, group) -> tuple[ConnectingCurve, object]:
    """The group of lanes as a road on a new reference line (lane ids unchanged), and the curve."""
    start, end = ends
    side = group[0].side  # -1: lanes right of the reference line
    first, last = group[0].id, group[-1].id
    centre0 = 0.5 * (start.inner[first] + start.outer[last])
    centre1 = 0.5 * (end.inner[first] + end.outer[last])
    chord = centre1 - centre0
    d0 = np.array([math.cos(start.heading), math.sin(start.heading)])
    d1 = np.array([math.cos(end.heading), math.sin(end.heading)])
    turn = (d0[0] * chord[1] - d0[1] * chord[0]) + (chord[0] * d1[1] - chord[1] * d1[0])  # > 0: a left turn
    # the reference line runs on the outside of the turn: lanes on the inside keep it at their inner border
    outside = turn * side < 0 and abs(turn) > TOLERANCE
    x0 = start.outer[last] if outside else start.inner[first]
    x1 = end.outer[last] if outside else end.inner[first]
    curve = hermite_curve(x0[0], x0[1], start.heading, x1[0], x1[1], end.heading)
    length = curve.length
    scale = length / road.length if road.length > 0 else 0.0
    widths = {lane.id: smooth_step(_width(start, lane.id), _width(end, lane.id), length) for lane in group}
    lane_offset = EMPTY_PROFILE
    if outside:  # the lanes lie between the reference line and the offset: their widths summed, other side
        lane_offset = cubic_record(-side * np.sum(list(widths.values()), axis=0), extend_first=False)
    section = road.lane_sections[0]
    lanes = [lane for lane in section.lanes if lane.id == 0]
    lanes += [_scaled_lane(lane, scale, widths[lane.id]) for lane in group]
    elevation = EMPTY_PROFILE
    if len(road.elevation) or len(start.road.elevation) or len(end.road.elevation):
        elevation = hermite_profile(start.z, start.grade, end.z, end.grade, length)
    rebuilt = replace(
        road, length=length, reference_line=ReferenceLine((curve.geometry,)),
        lane_sections=(replace(section, s0=0.0, lanes=tuple(lanes)),),
        types=tuple(replace(t, s0=min(t.s0 * scale, length)) for t in road.types),
        elevation=elevation, superelevation=EMPTY_PROFILE, shape=(), lane_offset=lane_offset,
        objects=tuple(replace(o, s=min(o.s * scale, length)) for o in road.objects),
        signals=tuple(replace(x, s=min(x.s * scale, length)) for x in road.signals),
        signal_references=tuple(replace(x, s=min(x.s * scale, length)) for x in road.signal_references),
    )
    return curve, rebuilt


def _scaled_lane(lane, scale: float, width: np.ndarray):
    """The lane on a road whose s is scaled by ``scale``, with one width record."""
    return replace(lane, widths=cubic_record(width), borders=EMPTY_PROFILE, heights=(),
                   road_marks=tuple(replace(m, s_offset=m.s_offset * scale) for m in lane.road_marks),
                   records=tuple(replace(r, s0=r.s0 * scale) for r in lane.records))


def _renumbered(road, mapping: dict):
    """The road with its side lanes renumbered (old id -> new id)."""
    if all(old == new for old, new in mapping.items()):
        return road
    section = road.lane_sections[0]
    lanes = tuple(replace(lane, id=mapping.get(lane.id, lane.id)) for lane in section.lanes)
    return replace(road, lane_sections=(replace(section, lanes=lanes),))


def _connections(junction, replaced: dict) -> list:
    """The junction's connections after its connecting roads were rebuilt, split or dropped."""
    connections, used = [], {c.id for c in junction.connections}
    next_id = _next_id(used)
    for connection in junction.connections:
        if connection.connecting_road not in replaced:
            connections.append(connection)
            continue
        for k, (new_road, mapping) in enumerate(replaced[connection.connecting_road]):
            links = tuple(LaneLink(link.from_lane, mapping[link.to_lane]) for link in connection.lane_links
                          if link.to_lane in mapping)
            if not links and connection.lane_links:
                continue
            if new_road.id == connection.connecting_road:
                connections.append(replace(connection, lane_links=links))
            else:
                connections.append(Connection(str(next_id), connection.incoming_road, new_road.id,
                                              connection.contact_point, links))
                next_id += 1
    return connections


def _unlink_junctions(road, gone: set):
    """The road without its links to junctions that were dropped."""
    changes = {}
    for name in ("predecessor", "successor"):
        link = getattr(road, name)
        if link is not None and link.element_type == "junction" and link.element_id in gone:
            changes[name] = None
    return replace(road, **changes) if changes else road
