"""Junction rules from ASAM's quality checker that the consistency rules of topology.py do not cover: roads that
need a junction, connecting roads used as incoming roads or in several connections, a connection's contact point
against the connecting road's own links, and the driving direction of junction laneLinks."""

from __future__ import annotations

from collections import defaultdict

from tavf_mapkit.validate.finding import ERROR, WARNING, Hit
from tavf_mapkit.validate.registry import rule


def junctions_with_connecting_roads(odr):
    """The junctions whose connections name a connecting road: not the direct junctions, whose @linkedRoad is a
    road outside the junction that the incoming road runs into."""
    return [junction for junction in odr.junctions if junction.type != "direct"]


@rule("topology.junction-needed", ERROR,
      summary="At most one road outside junctions links directly to each end of a road (predecessor/successor with "
              "@elementType road and @contactPoint); where several do, the roads meet in a junction.",
      why="A road end with two direct neighbours is ambiguous: readers pick one of them, and lanes overlap where "
          "the other begins. A junction says which lanes connect.")
def junction_needed(ctx, rule):
    users = defaultdict(list)
    for road in ctx.odr.roads:
        if road.in_junction:
            continue  # a junction's connecting roads share their neighbours by design
        for side, link in (("start", road.predecessor), ("end", road.successor)):
            if link is not None and link.element_type == "road" and link.contact_point in ("start", "end"):
                users[link.element_id, link.contact_point].append(road.id)
    roads = ctx.odr.road_by_id
    for (road_id, contact), linking in users.items():
        if len(linking) > 1:
            target = roads.get(road_id)
            yield Hit(f"{len(linking)} roads link directly to its {contact} (roads {', '.join(linking)}): a junction "
                      "is needed", road=road_id, s=None if target is None else 0.0 if contact == "start"
                      else target.length, line=None if target is None else target.line)


@rule("topology.incoming-road", ERROR,
      summary="A junction connection's incoming road is not itself a connecting road (a road with @junction).",
      why="Connecting roads exist only inside their junction; a connection that starts from one chains junctions "
          "without a road between them, which routers do not expect.")
def incoming_road(ctx, rule):
    roads = ctx.odr.road_by_id
    for junction in ctx.odr.junctions:
        for connection in junction.connections:
            incoming = roads.get(connection.incoming_road)
            if incoming is not None and incoming.in_junction:
                yield Hit(f"junction {junction.id} connection {connection.id}: incoming road {incoming.id} belongs to "
                          f"junction {incoming.junction}", road=incoming.id, line=junction.line)


@rule("topology.connection-unique", ERROR,
      summary="In an OpenDRIVE 1.7 file, each connecting road is the connecting road of exactly one junction "
              "<connection> (the rule of 1.7; 1.8 allows one per incoming road, earlier versions say nothing).",
      why="A connecting road carries one path through the junction; two connections for it make its lane links "
          "depend on which one a reader takes.")
def connection_unique(ctx, rule):
    if (ctx.odr.header.rev_major, ctx.odr.header.rev_minor) != (1, 7):
        return
    uses = defaultdict(list)
    for junction in junctions_with_connecting_roads(ctx.odr):
        for connection in junction.connections:
            if connection.connecting_road:
                uses[connection.connecting_road].append((junction, connection))
    for road_id, places in uses.items():
        if len(places) > 1:
            names = ", ".join(f"junction {junction.id} connection {connection.id}" for junction, connection in places)
            yield Hit(f"connecting road of {len(places)} connections ({names})", road=road_id,
                      line=places[1][0].line)


@rule("topology.connection-contact", ERROR,
      summary="A junction connection with @contactPoint start is the connecting road's predecessor link: that link "
              "names the incoming road; with end, the successor link does.",
      why="The contact point says which end of the connecting road touches the incoming road; when the road's own "
          "link says otherwise, readers run the connecting road in opposite directions.")
def connection_contact(ctx, rule):
    roads = ctx.odr.road_by_id
    for junction in junctions_with_connecting_roads(ctx.odr):
        for connection in junction.connections:
            connecting = roads.get(connection.connecting_road)
            if connecting is None or connection.contact_point not in ("start", "end"):
                continue
            name = "predecessor" if connection.contact_point == "start" else "successor"
            link = getattr(connecting, name)
            if link is None or link.element_type != "road" or link.contact_point not in ("start", "end"):
                continue
            if link.element_id != connection.incoming_road:
                yield Hit(f"junction {junction.id} connection {connection.id} (contact point {connection.contact_point}, "
                          f"incoming road {connection.incoming_road}): the road's {name} is road {link.element_id}",
                          road=connecting.id, s=0.0 if name == "predecessor" else connecting.length,
                          line=connecting.line)


#: lane types traffic drives along in one direction (a sidewalk or shoulder has none: CARLA links them through
#: its junctions as they lie)
DIRECTED_LANE_TYPES = frozenset({"driving", "entry", "exit", "onRamp", "offRamp", "connectingRamp", "slipLane",
                                 "biking", "bus", "taxi", "HOV", "mwyEntry", "mwyExit"})


def _drives_along_s(lane, road) -> bool | None:
    """Whether traffic on the lane drives in the direction of s (None: both directions, or a lane without a
    direction). Right-hand traffic drives along s on the right (negative ids), left-hand traffic on the left;
    @direction reversed flips it."""
    direction = lane.attrib.get("direction", "standard")
    if direction == "both" or lane.type not in DIRECTED_LANE_TYPES:
        return None
    along = (lane.id < 0) == (road.rule != "LHT")
    return not along if direction == "reversed" else along


@rule("topology.junction-lane-direction", WARNING,
      summary="A junction laneLink joins a lane that drives towards the junction to a lane of the connecting road "
              "that drives away from the incoming road (lanes vehicles drive along one way; driving side from each "
              "road's @rule, lane @direction).",
      why="A laneLink against the driving direction connects a lane leaving the junction, or the opposite lane of "
          "the connecting road: routes through the junction turn into oncoming traffic.")
def junction_lane_direction(ctx, rule):
    roads = ctx.odr.road_by_id
    for junction in junctions_with_connecting_roads(ctx.odr):
        for connection in junction.connections:
            connecting, incoming = roads.get(connection.connecting_road), roads.get(connection.incoming_road)
            if connecting is None or incoming is None or connection.contact_point not in ("start", "end"):
                continue
            link = connecting.predecessor if connection.contact_point == "start" else connecting.successor
            if link is None or link.element_type != "road" or link.contact_point not in ("start", "end") \
                    or link.element_id != incoming.id or not connecting.lane_sections or not incoming.lane_sections:
                continue  # which end of the incoming road is meant is unknown (topology.connection-contact)
            incoming_section = incoming.lane_sections[0 if link.contact_point == "start" else -1]
            connecting_section = connecting.lane_sections[0 if connection.contact_point == "start" else -1]
            for lane_link in connection.lane_links:
                source = incoming_section.by_id.get(lane_link.from_lane)
                target = connecting_section.by_id.get(lane_link.to_lane)
                if source is None or target is None:
                    continue
                source_along, target_along = _drives_along_s(source, incoming), _drives_along_s(target, connecting)
                # towards the junction: along s if the incoming road's end touches it; away from the incoming
                # road: along s if the connecting road starts there
                wrong = []
                if source_along is not None and source_along != (link.contact_point == "end"):
                    wrong.append(f"lane {source.id} of road {incoming.id} drives away from the junction")
                if target_along is not None and target_along != (connection.contact_point == "start"):
                    wrong.append(f"lane {target.id} drives towards road {incoming.id}")
                if wrong:
                    yield Hit(f"junction {junction.id} connection {connection.id}: laneLink {lane_link.from_lane} -> "
                              f"{lane_link.to_lane} against the driving direction ({'; '.join(wrong)})",
                              road=connecting.id, lane=target.id, line=junction.line)
