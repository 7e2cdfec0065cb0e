"""Which lane ends touch which: the links of an OpenDRIVE map as a symmetric relation between lane ends.

A lane end is ``(road_index, section_index, lane_id, "start" | "end")`` in terms of s. Lane-section links,
road-to-road links with contact points and junction connections all become pairs of touching ends; the
driving direction decides later which way an edge of the lane graph runs, so links written "backwards"
(incoming roads that are really outgoing, predecessor/successor pairs seen from either side) need no
special cases.
"""

from __future__ import annotations

import math

LaneEnd = tuple[int, int, int, str]


def _section_at(road, contact: str) -> int:
    return 0 if contact == "start" else len(road.lane_sections) - 1


def _end_point(road, contact: str) -> tuple[float, float]:
    x, y, *_ = road.reference_point(0.0 if contact == "start" else road.length)
    return float(x[0]), float(y[0])


def lane_end_pairs(odr) -> list[tuple[LaneEnd, LaneEnd]]:
    """Every pair of touching lane ends named by the map's links (each pair once or more, either order)."""
    pairs: list[tuple[LaneEnd, LaneEnd]] = []
    index = odr.road_index
    for r, road in enumerate(odr.roads):
        sections = road.lane_sections
        last = len(sections) - 1
        for k, section in enumerate(sections):
            for lane in section.side_lanes:
                if lane.successor is not None and k < last:
                    pairs.append(((r, k, lane.id, "end"), (r, k + 1, lane.successor, "start")))
                if lane.predecessor is not None and k > 0:
                    pairs.append(((r, k, lane.id, "start"), (r, k - 1, lane.predecessor, "end")))
        for link, own_end, k, attribute in ((road.successor, "end", last, "successor"),
                                           (road.predecessor, "start", 0, "predecessor")):
            if link is None or link.element_type != "road" or link.element_id not in index or not sections:
                continue
            other_index = index[link.element_id]
            other = odr.roads[other_index]
            if not other.lane_sections:
                continue
            contact = link.contact_point or ("start" if own_end == "end" else "end")
            other_section = _section_at(other, contact)
            for lane in sections[k].side_lanes:
                target = getattr(lane, attribute)
                if target is not None:
                    pairs.append(((r, k, lane.id, own_end), (other_index, other_section, target, contact)))
    for junction in odr.junctions:
        for connection in junction.connections:
            incoming = index.get(connection.incoming_road)
            connecting = index.get(connection.connecting_road)
            if incoming is None or connecting is None:
                continue
            incoming_road, connecting_road = odr.roads[incoming], odr.roads[connecting]
            if not incoming_road.lane_sections or not connecting_road.lane_sections:
                continue
            contact = connection.contact_point or "start"
            incoming_end = _junction_end(incoming_road, junction.id, connecting_road, contact)
            incoming_section = _section_at(incoming_road, incoming_end)
            connecting_section = _section_at(connecting_road, contact)
            for link in connection.lane_links:
                pairs.append(((incoming, incoming_section, link.from_lane, incoming_end),
                              (connecting, connecting_section, link.to_lane, contact)))
    return pairs


def _junction_end(road, junction_id: str, connecting_road, contact: str) -> str:
    """The end of an incoming road that touches the junction (by its links, else by geometry)."""
    at_end = road.successor is not None and road.successor.element_type == "junction" \
        and road.successor.element_id == junction_id
    at_start = road.predecessor is not None and road.predecessor.element_type == "junction" \
        and road.predecessor.element_id == junction_id
    if at_end != at_start:
        return "end" if at_end else "start"
    target = _end_point(connecting_road, contact)
    start, end = _end_point(road, "start"), _end_point(road, "end")
    return "start" if math.dist(start, target) < math.dist(end, target) else "end"
