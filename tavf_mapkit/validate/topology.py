"""Topology rules: ids, links to existing roads, junctions and lanes, geometric consistency of contact points,
lane links in both directions, junction connections, dead ends."""

from __future__ import annotations

from collections import Counter, defaultdict

import numpy as np

from tavf_mapkit.validate.context import angle_difference
from tavf_mapkit.validate.finding import ERROR, INFO, WARNING, Hit
from tavf_mapkit.validate.registry import rule

_CONTACTS = ("start", "end")
#: lane sections sampled at once for the borders at road ends (as the opendrive stage's curve repair batches)
SECTIONS_PER_BATCH = 2000


def _links(road):
    """(side, link) of a road: side is the road's own end ("start" for predecessor, "end" for successor)."""
    return [(side, link) for side, link in (("start", road.predecessor), ("end", road.successor)) if link is not None]


def _section_at(road, contact: str):
    if not road.lane_sections:
        return None
    return road.lane_sections[0] if contact == "start" else road.lane_sections[-1]


@rule("topology.duplicate-id", ERROR,
      summary="Road ids are unique, and so are junction ids and controller ids.",
      why="Links name roads, junctions and controllers by id; with two candidates every reader picks one, "
          "differently (the ASAM schema rejects the file). SUMO netconvert writes a joined traffic light's "
          "controller once per junction it controls.")
def duplicate_ids(ctx, rule):
    for kind, items in (("road", ctx.odr.roads), ("junction", ctx.odr.junctions),
                        ("controller", ctx.odr.controllers)):
        counts = Counter(item.id for item in items)
        seen = set()
        for item in items:
            if counts[item.id] > 1 and item.id in seen:
                yield Hit(f"{kind} id {item.id!r} is used {counts[item.id]} times",
                          road=item.id if kind == "road" else None, line=getattr(item, "line", None))
            seen.add(item.id)


@rule("topology.missing-road", ERROR,
      summary="Every road link and junction connection names a road that exists.",
      why="A link to nothing breaks routing: vehicles reach the end of the road and have nowhere to go.")
def missing_road(ctx, rule):
    roads = ctx.odr.road_by_id
    for road in ctx.odr.roads:
        for side, link in _links(road):
            if link.element_type == "road" and link.element_id not in roads:
                name = "predecessor" if side == "start" else "successor"
                yield Hit(f"{name} is road {link.element_id}, which does not exist", road=road.id, line=road.line)
    for junction in ctx.odr.junctions:
        for connection in junction.connections:
            for what, road_id in (("incoming", connection.incoming_road), ("connecting", connection.connecting_road)):
                if road_id and road_id not in roads:
                    yield Hit(f"junction {junction.id} connection {connection.id}: {what} road {road_id} does not "
                              "exist", line=junction.line)


def _missing_junction_links(odr):
    """Missing junction id -> list of (road, side) that link to it."""
    junctions = odr.junction_by_id
    users = defaultdict(list)
    for road in odr.roads:
        for side, link in _links(road):
            if link.element_type == "junction" and link.element_id not in junctions:
                users[link.element_id].append((road, side))
    return users


def _members_of_missing_junctions(odr):
    junctions = odr.junction_by_id
    members = defaultdict(list)
    for road in odr.roads:
        if road.in_junction and road.junction not in junctions:
            members[road.junction].append(road)
    return members


@rule("topology.missing-junction", ERROR,
      summary="A junction that roads belong to (@junction) or that several roads link to exists.",
      why="The junction holds the connections between its roads; without it they are not connected and its "
          "connecting roads float free.")
def missing_junction(ctx, rule):
    members = _members_of_missing_junctions(ctx.odr)
    for junction_id, roads in members.items():
        for road in roads:
            yield Hit(f"road belongs to junction {junction_id}, which does not exist", road=road.id, line=road.line)
    for junction_id, users in _missing_junction_links(ctx.odr).items():
        if len(users) > 1 or junction_id in members:
            for road, side in users:
                yield Hit(f"{'predecessor' if side == 'start' else 'successor'} is junction {junction_id}, which "
                          f"does not exist ({len(users)} road ends link to it)", road=road.id, line=road.line)


@rule("topology.dead-end-junction-link", WARNING,
      summary="A single road end links to a junction that does not exist and nothing else refers to it.",
      why="No connection is lost (the road end is a dead end either way), but the reference dangles; SUMO "
          "netconvert writes such links for dead-end nodes, 40 of them in DLR's TAVF network.")
def dead_end_junction_link(ctx, rule):
    members = _members_of_missing_junctions(ctx.odr)
    for junction_id, users in _missing_junction_links(ctx.odr).items():
        if len(users) == 1 and junction_id not in members:
            road, side = users[0]
            yield Hit(f"{'predecessor' if side == 'start' else 'successor'} is junction {junction_id}, which does "
                      "not exist; the road end is a dead end", road=road.id,
                      s=0.0 if side == "start" else road.length, line=road.line)


def _junction_side(incoming, junction_id: str, point, ends, index) -> str | None:
    """Which end of the incoming road touches the junction (the one nearer ``point`` if both link to it)."""
    sides = [side for side, link in _links(incoming) if link.element_type == "junction" and link.element_id == junction_id]
    if not sides:
        return None
    return min(sides, key=lambda s: np.hypot(*(ends.at(index[incoming.id], s)[0] - point)))


def _contacts(ctx):
    """What the file says touches, each once: (road, end, lane, other road, other end, other lane, origin, line).

    Lane pairs come from lane links across road links and from junction laneLinks; linked roads without any lane
    pair are compared by their reference lines (lane None). The ASAM rule is about lanes: SUMO netconvert, for
    one, starts a junction's connecting road at the border of the lane it continues, not at the incoming road's
    reference line, and the lanes still meet exactly.
    """
    cache = ctx.notes.setdefault("_contacts", {})
    if "value" in cache:
        return cache["value"]
    odr, ends = ctx.odr, ctx.road_ends
    index, roads = odr.road_index, odr.road_by_id
    contacts, seen, linked_roads = [], set(), []  # linked_roads: road links without lane pairs

    def add(road, side, lane, other, other_side, other_lane, origin, line):
        key = frozenset({(road.id, side, lane), (other.id, other_side, other_lane)})
        if key not in seen:
            seen.add(key)
            contacts.append((road, side, lane, other, other_side, other_lane, origin, line))

    for road in odr.roads:
        for side, link in _links(road):
            if link.element_type != "road" or link.element_id not in roads:
                continue
            other = roads[link.element_id]
            other_side = link.contact_point
            if other_side not in _CONTACTS:
                point = ends.at(index[road.id], side)[0]
                other_side = "start" if (np.hypot(*(ends.start_xy[index[other.id]] - point))
                                         <= np.hypot(*(ends.end_xy[index[other.id]] - point))) else "end"
            origin = f"{'predecessor' if side == 'start' else 'successor'} road {other.id}"
            section, other_section = _section_at(road, side), _section_at(other, other_side)
            pairs = 0
            if section is not None and other_section is not None:
                for lane in section.side_lanes:
                    target = lane.predecessor if side == "start" else lane.successor
                    if (target is not None and target != 0 and target in other_section.by_id
                            and "none" not in (lane.type, other_section.by_id[target].type)):
                        add(road, side, lane.id, other, other_side, target, origin, lane.line)
                        pairs += 1
            if not pairs:
                linked_roads.append((road, side, None, other, other_side, None, origin, road.line))
    for junction in odr.junctions:
        for connection in junction.connections:
            incoming, connecting = roads.get(connection.incoming_road), roads.get(connection.connecting_road)
            if incoming is None or connecting is None or connection.contact_point not in _CONTACTS:
                continue
            point = ends.at(index[connecting.id], connection.contact_point)[0]
            side = _junction_side(incoming, junction.id, point, ends, index)
            if side is None:
                continue  # topology.junction-connection reports it
            origin = f"junction {junction.id} connection {connection.id}"
            in_section, c_section = _section_at(incoming, side), _section_at(connecting, connection.contact_point)
            for lane_link in connection.lane_links:
                if (in_section is not None and c_section is not None and lane_link.from_lane in in_section.by_id
                        and lane_link.to_lane in c_section.by_id and lane_link.from_lane and lane_link.to_lane
                        and "none" not in (in_section.by_id[lane_link.from_lane].type,
                                           c_section.by_id[lane_link.to_lane].type)):
                    add(incoming, side, lane_link.from_lane, connecting, connection.contact_point, lane_link.to_lane,
                        origin, junction.line)
    with_lanes = {(c[0].id, c[1], c[3].id, c[4]) for c in contacts}
    with_lanes |= {(c[3].id, c[4], c[0].id, c[1]) for c in contacts}
    for contact in linked_roads:
        road, side, _, other, other_side = contact[:5]
        if (road.id, side, other.id, other_side) not in with_lanes:
            with_lanes |= {(road.id, side, other.id, other_side), (other.id, other_side, road.id, side)}
            contacts.append(contact)
    cache["value"] = contacts
    return contacts


def _end_border_table(ctx) -> tuple[dict, np.ndarray]:
    """({(road id, end, lane id): row}, rows of inner x, y, outer x, y) at both ends of every road, vectorised
    over SECTIONS_PER_BATCH lane sections at a time (memory bounded by the batch, not the map). Rows of one
    array, not a pair of points per lane end: a city has hundreds of thousands of lane ends.

    A sampling step longer than any road yields exactly the start and end of every lane section.
    """
    cache = ctx.notes.setdefault("_end_borders", {})
    if "value" in cache:
        return cache["value"]
    from tavf_mapkit.opendrive.sampling import sample_lanes_at, section_samples

    odr = ctx.odr
    arrays = odr.arrays
    table: dict = {}
    rows = []
    count = 0
    if len(arrays.lane_id):
        step = float(arrays.road_length.max(initial=0.0)) + 1e6
        first_section = np.r_[True, arrays.section_road[1:] != arrays.section_road[:-1]]
        last_section = np.r_[arrays.section_road[1:] != arrays.section_road[:-1], True]
        for start in range(0, len(arrays.section_s0), SECTIONS_PER_BATCH):
            batch = np.arange(start, min(start + SECTIONS_PER_BATCH, len(arrays.section_s0)))
            sampling = sample_lanes_at(odr, *section_samples(arrays, step, True, batch))
            inner = sampling.points_at(sampling.t_inner)[:, :2]
            outer = sampling.points_at(sampling.t_outer)[:, :2]
            section = sampling.section_index
            road_index = arrays.section_road[section]
            s, s0, end = sampling.s, arrays.section_s0[section], arrays.section_end[section]
            at_start = first_section[section] & (s == s0)
            at_end = last_section[section] & (s == end)
            roads, lane_id = odr.roads, sampling.lane_id
            # a key comes from one side only, so filling side by side per batch gives the whole map's table
            for mask, side in ((at_start, "start"), (at_end, "end")):
                picked = np.flatnonzero(mask)
                rows.append(np.column_stack([inner[picked], outer[picked]]))
                for row, k in enumerate(picked, start=count):
                    table[(roads[road_index[k]].id, side, int(lane_id[k]))] = row
                count += len(picked)
    cache["value"] = table, np.concatenate(rows) if rows else np.zeros((0, 4))
    return cache["value"]


def _end_border(ctx, road, side, lane):
    """(inner xy, outer xy) of a lane at a road end, None where the lane is not there; lane None -> the
    reference line's end point (twice)."""
    if lane is None:
        point = ctx.road_ends.at(ctx.odr.road_index[road.id], side)[0]
        return point, point
    table, xy = _end_border_table(ctx)
    row = table.get((road.id, side, lane))
    return None if row is None else (xy[row, :2], xy[row, 2:])


def _contact_geometry(ctx, contacts):
    """Per contact: largest distance between corresponding borders, and the heading break in degrees."""
    cache = ctx.notes.setdefault("_contact_geometry", {})
    if "value" in cache:
        return cache["value"]
    ends, index = ctx.road_ends, ctx.odr.road_index
    xy = np.zeros((len(contacts), 4, 2))
    headings = np.empty(len(contacts))
    comparable = np.zeros(len(contacts), dtype=bool)
    for k, (road, side, lane, other, other_side, other_lane, _, _) in enumerate(contacts):
        a, b = _end_border(ctx, road, side, lane), _end_border(ctx, other, other_side, other_lane)
        # a lane missing at an end (e.g. a zero-length last section) gives nothing to compare
        comparable[k] = a is not None and b is not None
        if a is not None:
            xy[k, 0], xy[k, 1] = a
        if b is not None:
            xy[k, 2], xy[k, 3] = b
        headings[k] = ends.at(index[road.id], side)[1] - ends.at(index[other.id], other_side)[1]
    distance = np.maximum(np.hypot(*(xy[:, 0] - xy[:, 2]).T), np.hypot(*(xy[:, 1] - xy[:, 3]).T))
    heading = np.degrees(np.abs(angle_difference(headings, np.pi)))
    cache["value"] = (np.where(comparable, distance, 0.0), np.where(comparable, heading, 0.0))
    ctx.notes.pop("_end_borders", None)  # nothing else reads the border table: it need not outlive this
    return cache["value"]


def _describe(contact) -> str:
    _, side, lane, other, other_side, other_lane, origin, _ = contact
    if lane is None:
        return f"the reference line's {side} and road {other.id}'s {other_side} ({origin})"
    return f"lane {lane} at the {side} and lane {other_lane} at the {other_side} of road {other.id} ({origin})"


@rule("topology.contact-gap", ERROR, tolerance=0.05, unit="m",
      summary="Linked lanes meet: at the contact point the inner and outer borders of a lane and of the lane it "
              "links to (lane links across road links, junction laneLinks; lanes of type none excepted) are within "
              "the tolerance; linked roads without lane links are compared by their reference lines.",
      why="Linked lanes that do not meet make a gap or an overlap at every junction entry; routes jump.")
def contact_gap(ctx, rule):
    contacts = _contacts(ctx)
    if not contacts:
        return
    distance, _ = _contact_geometry(ctx, contacts)
    # one finding per pair of road ends, naming the worst lane: a misplaced road end displaces all its lanes
    worst: dict = {}
    for k in np.flatnonzero(distance > rule.tolerance):
        road, side, _, other, other_side = contacts[k][:5]
        key = (road.id, side, other.id, other_side)
        count, best = worst.get(key, (0, None))
        worst[key] = (count + 1, k if best is None or distance[k] > distance[best] else best)
    for count, k in worst.values():
        road, side, lane = contacts[k][:3]
        more = f" (and {count - 1} more lane pairs of this link)" if count > 1 else ""
        yield Hit(f"{_describe(contacts[k])} are {distance[k]:.3g} m apart{more}", road=road.id, lane=lane,
                  s=0.0 if side == "start" else road.length, line=contacts[k][7])


@rule("topology.contact-heading", WARNING, tolerance=5.0, unit="deg",
      summary="Linked roads continue each other: the reference-line headings at the contact points agree "
              "(opposite outward directions) within the tolerance.",
      why="A heading break at a link is a kink in every lane that crosses it; a reversed contact point makes "
          "lanes run against each other.")
def contact_heading(ctx, rule):
    contacts = _contacts(ctx)
    if not contacts:
        return
    _, heading = _contact_geometry(ctx, contacts)
    reported = set()
    for k in np.flatnonzero(heading > rule.tolerance):
        road, side, _, other, other_side = contacts[k][:5]
        if (road.id, side, other.id, other_side) in reported:
            continue
        reported.add((road.id, side, other.id, other_side))
        yield Hit(f"heading at the {side} differs by {heading[k]:.3g} deg from the {other_side} of road {other.id} "
                  f"({contacts[k][6]})", road=road.id, s=0.0 if side == "start" else road.length, line=road.line)


def _lane_link_targets(odr):
    """(road, section index, lane, direction, target road, target section, road-link contact) for every lane link
    that can be resolved to a lane section (inside the road, or across a road-to-road link)."""
    out = []
    for road in odr.roads:
        last = len(road.lane_sections) - 1
        for k, section in enumerate(road.lane_sections):
            for lane in section.side_lanes:
                for direction, target_id in (("predecessor", lane.predecessor), ("successor", lane.successor)):
                    if target_id is None:
                        continue
                    neighbour = k - 1 if direction == "predecessor" else k + 1
                    if 0 <= neighbour <= last:
                        out.append((road, k, lane, direction, target_id, road, neighbour, None))
                        continue
                    link = road.predecessor if direction == "predecessor" else road.successor
                    if link is None or link.element_type != "road" or link.element_id not in odr.road_by_id:
                        continue  # into a junction (its laneLinks say where) or nowhere
                    other = odr.road_by_id[link.element_id]
                    contact = link.contact_point or ("end" if direction == "predecessor" else "start")
                    if not other.lane_sections:
                        continue
                    target_section = 0 if contact == "start" else len(other.lane_sections) - 1
                    out.append((road, k, lane, direction, target_id, other, target_section, contact))
    return out


@rule("topology.lane-link-target", ERROR,
      summary="A lane's predecessor/successor names a lane that exists in the adjoining lane section (next section "
              "of the same road, or the linked road's section at the contact point).",
      why="A lane link to a missing lane breaks lane-level routing: the lane leads nowhere.")
def lane_link_target(ctx, rule):
    for road, k, lane, direction, target_id, other, section, contact in _lane_link_targets(ctx.odr):
        if target_id not in other.lane_sections[section].by_id:
            where = (f"the next lane section (s={other.lane_sections[section].s0:g})" if other is road
                     else f"road {other.id} at its {contact}")
            yield Hit(f"{direction} lane {target_id} does not exist in {where}", road=road.id, lane=lane.id,
                      s=road.lane_sections[k].s0, line=lane.line)


def _facing_sections(odr):
    """Pairs of lane sections that meet, each as (road, section index, the lane link that crosses the meeting):
    consecutive sections of a road, and the end section of a road outside junctions with the section of the road
    it links to at the contact point (a junction's own roads link their end lanes through the junction's
    laneLinks, where the standard says the lane's own link is omitted)."""
    for road in odr.roads:
        n = len(road.lane_sections)
        for k in range(n - 1):
            yield (road, k, "successor"), (road, k + 1, "predecessor")
        if road.in_junction or not n:
            continue
        for side, link in (("predecessor", road.predecessor), ("successor", road.successor)):
            if link is None or link.element_type != "road" or link.element_id not in odr.road_by_id:
                continue
            other = odr.road_by_id[link.element_id]
            if not other.lane_sections:
                continue
            contact = link.contact_point or ("end" if side == "predecessor" else "start")
            yield ((road, 0 if side == "predecessor" else n - 1, side),
                   (other, 0 if contact == "start" else len(other.lane_sections) - 1,
                    "predecessor" if contact == "start" else "successor"))


@rule("topology.lane-link-symmetry", WARNING,
      summary="Lane links are given in both directions: if lane A names lane B as its successor (next lane section, "
              "or a linked road's section at the contact point, for a road outside junctions), B names A as its "
              "predecessor (or successor, end to end).",
      why="One-sided links make routing depend on the direction of travel; many readers follow only one side. The "
          "finding names lane B, the one whose link is missing. Where two lanes merge into one, OpenDRIVE 1.4-1.7 "
          "give the merged lane one predecessor: the other lane is reported (ASAM's checker does the same).")
def lane_link_symmetry(ctx, rule):
    reported = set()
    for first, second in _facing_sections(ctx.odr):
        for (road, k, direction), (other, j, back) in ((first, second), (second, first)):
            here, there = road.lane_sections[k], other.lane_sections[j]
            for lane in here.side_lanes:
                target = there.by_id.get(getattr(lane, direction)) if getattr(lane, direction) else None
                if target is None:
                    continue  # topology.lane-link-target reports a link to a lane that is not there
                named = getattr(target, back)
                if named == lane.id:
                    continue
                key = (other.id, j, target.id, road.id, k, lane.id)
                if key in reported:
                    continue
                reported.add(key)
                where = "the lane section before" if other is road and j > k else \
                    "the next lane section" if other is road else f"road {road.id}"
                instead = f"names lane {named} instead" if named is not None else f"has no {back}"
                yield Hit(f"lane {target.id} {instead}, but lane {lane.id} of {where} names it as its {direction}",
                          road=other.id, lane=target.id, s=there.s0, line=target.line)


@rule("topology.lane-section-link", WARNING, tolerance=0.01, unit="m",
      summary="Where one lane section follows another, every driving lane wider than the tolerance at the boundary "
              "is linked to a lane of the other section.",
      why="Unlinked lanes across a section boundary end routing in the middle of a road.")
def lane_section_link(ctx, rule):
    for road in ctx.odr.roads:
        for k in range(len(road.lane_sections) - 1):
            before, after = road.lane_sections[k], road.lane_sections[k + 1]
            boundary = after.s0
            if boundary - before.s0 <= 0:
                continue
            for section, direction in ((before, "successor"), (after, "predecessor")):
                other = after if section is before else before
                borders = road.lane_borders(road.lane_sections.index(section), [boundary])
                for lane in section.side_lanes:
                    if lane.type != "driving" or getattr(lane, direction) is not None:
                        continue
                    if not any(candidate.side == lane.side for candidate in other.side_lanes):
                        continue
                    inner = borders.get(lane.id - lane.side, borders[0])
                    width = abs(float(borders[lane.id][0] - inner[0]))
                    if width > rule.tolerance:
                        yield Hit(f"driving lane ({width:.2f} m wide) has no {direction} across the lane-section "
                                  f"boundary at s={boundary:g}", road=road.id, lane=lane.id, s=boundary,
                                  line=lane.line)


@rule("topology.junction-connection", ERROR,
      summary="Junction connections are consistent: the connecting road belongs to the junction (@junction), the "
              "incoming road links to the junction, @contactPoint is start or end.",
      why="Routers enter a junction through these statements; a contradiction makes a turn disappear or appear "
          "from the wrong road.")
def junction_connection(ctx, rule):
    odr = ctx.odr
    for junction in odr.junctions:
        direct = junction.type == "direct"
        for connection in junction.connections:
            label = f"junction {junction.id} connection {connection.id}"
            connecting = odr.road_by_id.get(connection.connecting_road)
            incoming = odr.road_by_id.get(connection.incoming_road)
            if connection.contact_point not in _CONTACTS:
                yield Hit(f"{label}: @contactPoint={connection.contact_point!r}, expected start or end",
                          road=connection.connecting_road, line=junction.line)
            if connecting is not None and not direct and connecting.junction != junction.id:
                belongs = f"junction {connecting.junction}" if connecting.in_junction else "no junction"
                yield Hit(f"{label}: connecting road {connecting.id} belongs to {belongs}", road=connecting.id,
                          line=junction.line)
            if incoming is not None and not direct and not any(
                    link.element_type == "junction" and link.element_id == junction.id for _, link in _links(incoming)):
                    yield Hit(f"{label}: incoming road {incoming.id} does not link to junction {junction.id}",
                              road=incoming.id, line=junction.line)


@rule("topology.junction-lane-link", ERROR,
      summary="A junction laneLink's @from lane exists on the incoming road at the junction and its @to lane on "
              "the connecting road at the contact point; where that lane states a link back, it agrees.",
      why="Lane-level routes through a junction follow these links; a wrong lane id sends traffic into a lane "
          "that is not there or into oncoming traffic.")
def junction_lane_link(ctx, rule):
    odr = ctx.odr
    for junction in odr.junctions:
        for connection in junction.connections:
            incoming = odr.road_by_id.get(connection.incoming_road)
            connecting = odr.road_by_id.get(connection.connecting_road)
            if incoming is None or connecting is None or connection.contact_point not in _CONTACTS:
                continue
            label = f"junction {junction.id} connection {connection.id}"
            sides = [side for side, link in _links(incoming)
                     if link.element_type == "junction" and link.element_id == junction.id]
            incoming_section = _section_at(incoming, sides[0]) if len(sides) == 1 else None
            connecting_section = _section_at(connecting, connection.contact_point)
            back = "predecessor" if connection.contact_point == "start" else "successor"
            back_link = connecting.predecessor if back == "predecessor" else connecting.successor
            states_back = back_link is not None and back_link.element_type == "road" \
                and back_link.element_id == incoming.id
            for lane_link in connection.lane_links:
                if incoming_section is not None and lane_link.from_lane not in incoming_section.by_id:
                    yield Hit(f"{label}: laneLink from lane {lane_link.from_lane}, which road {incoming.id} does not "
                              f"have at its {sides[0]}", road=incoming.id, lane=lane_link.from_lane,
                              line=junction.line)
                target = connecting_section.by_id.get(lane_link.to_lane) if connecting_section else None
                if connecting_section is not None and target is None:
                    yield Hit(f"{label}: laneLink to lane {lane_link.to_lane}, which road {connecting.id} does not "
                              f"have at its {connection.contact_point}", road=connecting.id, lane=lane_link.to_lane,
                              line=junction.line)
                elif target is not None and states_back and getattr(target, back) not in (None, lane_link.from_lane):
                    yield Hit(f"{label}: laneLink {lane_link.from_lane} -> {lane_link.to_lane}, but lane "
                              f"{lane_link.to_lane}'s {back} is {getattr(target, back)}", road=connecting.id,
                              lane=lane_link.to_lane, line=target.line)


@rule("topology.dead-end", INFO,
      summary="Road ends without any link (listed, not a fault in itself).",
      why="Dead ends are where routes stop; in a city network most are extract borders, the rest are worth a look.")
def dead_end(ctx, rule):
    for road in ctx.odr.roads:
        if not any(lane.type == "driving" for section in road.lane_sections for lane in section.side_lanes):
            continue
        for side, link in (("start", road.predecessor), ("end", road.successor)):
            if link is None:
                yield Hit(f"no {'predecessor' if side == 'start' else 'successor'}: the road's {side} is a dead end",
                          road=road.id, s=0.0 if side == "start" else road.length, line=road.line)
