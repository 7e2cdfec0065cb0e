"""Lane rules from ASAM's quality checker that topology.py did not have: @level on one side, access records that
mix allow and deny, and lane links to or from a lane of zero width."""

from __future__ import annotations

import numpy as np

from tavf_mapkit.validate.finding import ERROR, WARNING, Hit
from tavf_mapkit.validate.registry import rule

#: a lane this narrow at a contact (m) has not begun or has ended there (ASAM's threshold)
ZERO_WIDTH = 1e-6


@rule("structure.lane-level", WARNING,
      summary="Lanes with @level true lie on the outside of a side: from the centre outwards no lane is @level false "
              "after one that is true; and linked lanes (across lane sections, road links and junction laneLinks) "
              "have the same @level.",
      why="@level true keeps a lane out of superelevation (a kerbside walk). A level lane between tilted ones, or "
          "a lane whose level changes at a link, gives a step in the road surface.")
def lane_level(ctx, rule):
    odr = ctx.odr
    for road in odr.roads:
        for section in road.lane_sections:
            for lanes in (section.left, section.right):
                level_seen = False
                for lane in sorted(lanes, key=lambda item: abs(item.id)):
                    if lane.level:
                        level_seen = True
                    elif level_seen:
                        yield Hit(f"lane is @level false outside a lane that is true (lane section at "
                                  f"s={section.s0:g})", road=road.id, lane=lane.id, s=section.s0, line=lane.line)
    for road, lane, other, target in _linked_lanes(odr):
        if lane.level != target.level:
            yield Hit(f"@level {str(lane.level).lower()}, but the lane {target.id} of road {other.id} it links to is "
                      f"{str(target.level).lower()}", road=road.id, lane=lane.id, line=lane.line)


def _lane_links(odr):
    """(road, section index, lane, its link "predecessor"/"successor", other road, its section index, linked lane,
    whether the link meets the linked lane's section at its start) for every lane link across lane sections and
    road links (with a contact point)."""
    roads = odr.road_by_id
    for road in odr.roads:
        sections = road.lane_sections
        for k, section in enumerate(sections):
            for lane in section.side_lanes:
                for name, neighbour in (("predecessor", k - 1), ("successor", k + 1)):
                    target_id = getattr(lane, name)
                    if target_id is None:
                        continue
                    if 0 <= neighbour < len(sections):
                        other, j, at_start = road, neighbour, name == "successor"
                    else:
                        link = getattr(road, name)
                        if link is None or link.element_type != "road" or link.contact_point not in ("start", "end"):
                            continue
                        other = roads.get(link.element_id)
                        if other is None or not other.lane_sections:
                            continue
                        j = 0 if link.contact_point == "start" else len(other.lane_sections) - 1
                        at_start = link.contact_point == "start"
                    target = other.lane_sections[j].by_id.get(target_id)
                    if target is not None:
                        yield road, k, lane, name, other, j, target, at_start


def _junction_lane_links(odr):
    """(incoming road, its lane, "start"/"end" of the incoming road at the junction, connecting road, its lane,
    the connection's contact point) for every junction laneLink whose connecting road states its link to the
    incoming road's end."""
    from tavf_mapkit.validate.junctions import junctions_with_connecting_roads

    roads = odr.road_by_id
    for junction in junctions_with_connecting_roads(odr):
        for connection in junction.connections:
            incoming, connecting = roads.get(connection.incoming_road), roads.get(connection.connecting_road)
            if incoming is None or connecting is None or not incoming.lane_sections or not connecting.lane_sections:
                continue
            link = connecting.predecessor if connection.contact_point == "start" else connecting.successor
            if link is None or link.element_type != "road" or link.contact_point not in ("start", "end"):
                continue
            incoming_section = incoming.lane_sections[0 if link.contact_point == "start" else -1]
            connecting_section = connecting.lane_sections[0 if connection.contact_point == "start" else -1]
            for lane_link in connection.lane_links:
                source = incoming_section.by_id.get(lane_link.from_lane)
                target = connecting_section.by_id.get(lane_link.to_lane)
                if source is not None and target is not None:
                    yield incoming, source, link.contact_point, connecting, target, connection.contact_point


def _linked_lanes(odr):
    """(road, lane, other road, linked lane) for every lane link and junction laneLink."""
    for road, _, lane, _, other, _, target, _ in _lane_links(odr):
        yield road, lane, other, target
    for incoming, source, _, connecting, target, _ in _junction_lane_links(odr):
        yield incoming, source, connecting, target


@rule("structure.lane-access", ERROR,
      summary="A lane's <access> records that start at the same s are all allow or all deny.",
      why="Allow lists what may use the lane, deny what may not; mixed at one s, readers disagree on whether "
          "anything not listed may drive there.")
def lane_access(ctx, rule):
    for road in ctx.odr.roads:
        for section in road.lane_sections:
            for lane in section.side_lanes:
                rules_at: dict = {}
                for record in lane.records:
                    if record.tag != "access" or "rule" not in record.attrib:
                        continue
                    key = round(record.s0, 6)
                    first = rules_at.setdefault(key, record.attrib["rule"])
                    if record.attrib["rule"] != first:
                        yield Hit(f"access records at s={record.s0:g} both {first} and {record.attrib['rule']}",
                                  road=road.id, lane=lane.id, s=record.s0, line=lane.line)


def _width_at(ctx, road, k: int, lane, at_start: bool) -> float | None:
    """The lane's width where its lane section starts or ends (None for a lane defined by borders). Both ends of a
    lane are evaluated in one call and kept for the map (two rules ask, and a lane of a junction's laneLinks is
    asked for by each link to it): a region has hundreds of thousands of such questions."""
    cache = ctx.notes.setdefault("_lane_end_widths", {})
    key = (id(road), k, id(lane))  # a lane object could be shared by sections (interned), its ends are not
    if key not in cache:
        if not len(lane.widths):
            cache[key] = None
        else:
            start = road.lane_sections[k].s0
            # at the end, a hair inside: a width record starting at the section's end is not yet in force
            end = max(float(np.nextafter(road.section_end(k), -np.inf)), start)
            cache[key] = tuple(lane.widths(np.array([start, end])).tolist())
    widths = cache[key]
    return None if widths is None else widths[0 if at_start else 1]


def _zero(width: float | None) -> bool:
    return width is not None and abs(width) < ZERO_WIDTH


@rule("topology.zero-width-link", ERROR,
      summary="A lane of zero width where its lane section starts has no predecessor, and where it ends no "
              "successor: neither its own link nor a junction laneLink.",
      why="A lane of zero width at a contact begins or ends there: it continues nothing and nothing continues it. "
          "Linked, routes start or end in a lane that is not there.")
def zero_width_link(ctx, rule):
    odr = ctx.odr
    reported = set()
    for road in odr.roads:
        for k, section in enumerate(road.lane_sections):
            for lane in section.side_lanes:
                for name, at_start in (("predecessor", True), ("successor", False)):
                    if getattr(lane, name) is not None and _zero(_width_at(ctx, road, k, lane, at_start)):
                        reported.add((road.id, k, lane.id, name))
                        s = section.s0 if at_start else road.section_end(k)
                        yield Hit(f"lane has zero width where its lane section {'starts' if at_start else 'ends'} "
                                  f"(s={s:g}) but a {name}", road=road.id, lane=lane.id, s=s, line=lane.line)
    for incoming, source, end, connecting, target, contact in _junction_lane_links(odr):
        for road, lane, at_start in ((incoming, source, end == "start"), (connecting, target, contact == "start")):
            k = 0 if at_start else len(road.lane_sections) - 1
            name = "predecessor" if at_start else "successor"
            if (road.id, k, lane.id, name) not in reported and _zero(_width_at(ctx, road, k, lane, at_start)):
                reported.add((road.id, k, lane.id, name))
                yield Hit(f"lane has zero width at the road's {'start' if at_start else 'end'} but a junction laneLink "
                          f"makes it a {name} ({incoming.id} lane {source.id} -> {connecting.id} lane {target.id})",
                          road=road.id, lane=lane.id, s=0.0 if at_start else road.length, line=lane.line)


@rule("topology.appearing-lane-link", ERROR,
      summary="No lane links to a lane that has zero width at the contact (lane links across lane sections and road "
              "links, junction laneLinks): where a lane appears beside another, the continuing lane is linked.",
      why="A lane of zero width at the contact is a lane that appears (or ends) there; linking to it instead of "
          "the lane that continues sends routes into a lane with no room.")
def appearing_lane_link(ctx, rule):
    odr = ctx.odr
    for road, k, lane, name, other, j, target, at_start in _lane_links(odr):
        if _zero(_width_at(ctx, other, j, target, at_start)):
            where = "the next lane section" if other is road else f"road {other.id}"
            yield Hit(f"{name} is lane {target.id} of {where}, which has zero width there (it appears beside the "
                      "lane that continues)", road=road.id, lane=lane.id, s=road.lane_sections[k].s0, line=lane.line)
    for incoming, source, end, connecting, target, contact in _junction_lane_links(odr):
        k = 0 if contact == "start" else len(connecting.lane_sections) - 1
        if _zero(_width_at(ctx, connecting, k, target, contact == "start")):
            yield Hit(f"junction laneLink to lane {target.id} of connecting road {connecting.id}, which has zero width "
                      f"at its {contact}", road=incoming.id, lane=source.id, line=source.line)
