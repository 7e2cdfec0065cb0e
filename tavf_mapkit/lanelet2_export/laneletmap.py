"""An OpenDRIVE map as Lanelet2 primitives: one lanelet per lane and lane section, bounds shared by
neighbours.

Steps (vectorised over the map but the per-lane, per-way and per-signal bookkeeping):

1. sample every lane section once, adaptively (no bound further than ``eps`` from the exact border) or every
   ``step`` metres, and evaluate each needed border there (``bounds.border_part``), in parts of whole lane
   sections (``parts``: a region's samples at once would exceed the map's allocation budget);
2. pick the lanes that get a lanelet (``mapping.lanelet_tags``) and orient each along its driving direction
   (``lanegraph.drives_with_s``: right-hand traffic drives right lanes with s, ``rule="LHT"`` mirrors it, an
   OpenDRIVE 1.8 ``direction="reversed"`` flips it): left bound = the border on the driver's left;
3. cut folded borders (``folds``) and choose the samples of sections Lanelet2 would misread (``untangle``);
4. join the corners of lane ends the map links (``lanegraph.topology.lane_end_pairs``), so Lanelet2's routing
   graph finds the same successors as our lane graph, and merge coinciding points into nodes
   (``nodes.merge_points``) -- never a lane end with a point of another section, so it finds no others;
5. tag every border way with its road mark's line type, adding explicit ``lane_change`` tags where the line
   type alone would tell Lanelet2 something else than the mark does for our lane graph; give every lanelet our
   centre line (``centreline``), and inside-out ones bounds of their own (``orientation``);
6. signals become regulatory elements (``regulatory``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tavf_mapkit.lanegraph.graph import lane_speed_limit
from tavf_mapkit.lanegraph.keys import drives_with_s
from tavf_mapkit.lanegraph.lanechange import lane_change_allowed, mark_at
from tavf_mapkit.lanegraph.topology import lane_end_pairs
from tavf_mapkit.lanelet2_export.bounds import border_part, join_borders, outermost_rows
from tavf_mapkit.lanelet2_export.centreline import centre_lines, join_centre_lines
from tavf_mapkit.lanelet2_export.folds import cut_folds
from tavf_mapkit.lanelet2_export.mapping import is_vehicle_lane, lane_change_tags, lanelet_tags, line_tags
from tavf_mapkit.lanelet2_export.nodes import FREE, merge_points
from tavf_mapkit.lanelet2_export.orientation import give_private_bounds
from tavf_mapkit.lanelet2_export.parts import PART_PAIRS, sample_in_parts
from tavf_mapkit.lanelet2_export.regulatory import signal_elements
from tavf_mapkit.lanelet2_export.untangle import untangle_sections
from tavf_mapkit.opendrive.surface import surface_frame

#: lane ends the map links are joined into one node when their corners lie at most this far apart (m); a
#: repaired build has them within a millimetre, further apart a link is broken and joining would bend the
#: lanes
JOIN_TOLERANCE = 0.1
#: lanes narrower than this everywhere get no lanelet: Lanelet2 cannot tell their left from their right bound
MIN_WIDTH = 0.01


@dataclass
class LaneletMap:
    """Primitives by index; ``osmxml.osm_text`` gives them ids. Ways hold node indices."""

    nodes: np.ndarray  # (n, 3) local x, y, z
    way_nodes: list[np.ndarray]
    way_tags: list[dict[str, str]]
    lanelets: list[dict] = field(default_factory=list)  # {"left", "right", "tags", "regulatory"}
    regulatory: list[dict] = field(default_factory=list)  # {"tags", "members": [(kind, index, role)]}
    # (road index, section index, lane id) of every lanelet
    lanelet_keys: list[tuple[int, int, int]] = field(default_factory=list)
    max_deviation: float | None = None  # adaptive sampling's largest measured distance to the exact border
    unjoined: int = 0  # linked lane ends whose corners were too far apart to join
    narrow: int = 0  # lanes left out for being narrower than MIN_WIDTH
    private_bounds: int = 0  # inside-out lanelets given bounds of their own (orientation.py)
    turned: int = 0  # lanelets Lanelet2 will still read against their lane


def build_lanelet_map(
    odr, eps: float = 0.01, step: float | None = None, part_pairs: int = PART_PAIRS
) -> LaneletMap:
    from tavf_mapkit.opendrive.sampling import section_samples

    arrays = odr.arrays
    max_deviation = None
    if step is None:
        from tavf_mapkit.mesh.adaptive import adaptive_samples

        samples = adaptive_samples(odr, eps)
        sample_section, sample_s, max_deviation = samples.section, samples.s, samples.max_deviation
    else:
        sample_section, sample_s = section_samples(arrays, step, include_end=True)
    per_section = np.bincount(sample_section, minlength=len(arrays.section_s0))

    # -- which lanes, which way round; their borders, centre lines and middles, part by part (parts.py) ----
    section_first = np.searchsorted(arrays.section_road, np.arange(len(odr.roads)), side="left")
    selected, border_parts, centre_parts, middles = [], [], [], []
    for sampling in sample_in_parts(odr, sample_section, sample_s, part_pairs):
        chosen = _select_lanes(odr, sampling, per_section, section_first)
        selected.append(chosen)
        border_parts.append(border_part(odr, sampling, chosen[0]))
        centre_parts.append(centre_lines(sampling, chosen[0]))
        middles.append(_middles(sampling, chosen[0], chosen[2], per_section))
    rows = np.concatenate([part[0] for part in selected])
    tags = [lane_tags for part in selected for lane_tags in part[1]]
    forward = np.concatenate([part[2] for part in selected])
    keys = [key for part in selected for key in part[3]]
    narrow = sum(part[4] for part in selected)
    borders = join_borders(border_parts, len(arrays.lane_id))
    centre = join_centre_lines(centre_parts)
    heading = np.concatenate([part[0] for part in middles])
    middle_point = np.concatenate([part[1] for part in middles])
    del selected, border_parts, centre_parts, middles
    inner = borders.inner(rows, arrays)
    right_side = arrays.lane_id[rows] < 0
    # the +t side is inside for right lanes, outside for left lanes
    plus_t = np.where(right_side, inner, rows)
    minus_t = np.where(right_side, rows, inner)
    left = np.where(forward, plus_t, minus_t)
    right = np.where(forward, minus_t, plus_t)

    # -- points: borders (folds cut), our centre lines, signal geometry ----------------------------------
    lanelet_of = {key: i for i, key in enumerate(keys)}
    row_of = {key: int(row) for key, row in zip(keys, rows)}
    joins, unjoined = _link_joins(odr, borders, centre, lanelet_of, row_of, arrays)
    border_points, border_keep, _ = cut_folds(borders.points, borders.border, borders.tangent)
    untangle_sections(arrays, borders, border_points, border_keep, left, right, forward)
    elements = signal_elements(odr, lanelet_of)
    parts = [border_points, centre.points]
    offset = len(border_points) + len(centre.points)
    element_points = []
    for element in elements:
        refers = np.arange(offset, offset + 2)
        offset += 2
        stop = np.arange(offset, offset + len(element.stop_points))
        offset += len(element.stop_points)
        parts += [element.refers_points, element.stop_points]
        element_points.append((refers, stop))
    group, shared = _merge_groups(arrays, borders, centre, rows, offset - len(border_points) - len(centre.points))
    node_of, positions = merge_points(np.concatenate(parts), joins, group, shared)

    # -- ways ---------------------------------------------------------------------------------------------
    used = np.unique(np.concatenate([left, right]))
    way_of_border = np.full(len(borders.start), -1, dtype=np.int64)
    way_nodes, way_tags = [], []
    marks = _BorderMarks(odr, borders, section_first, rows, forward)
    keep = np.concatenate([border_keep, centre.keep])
    for border, nodes in zip(used, _node_runs(borders.start[used], borders.count[used], node_of, keep)):
        way_of_border[border] = len(way_nodes)
        way_nodes.append(nodes)
        way_tags.append(marks.tags(int(border)))

    laneletmap = LaneletMap(
        positions, way_nodes, way_tags, max_deviation=max_deviation, unjoined=unjoined, narrow=narrow
    )
    centre_runs = _node_runs(centre.start + len(border_points), centre.count, node_of, keep)
    centre_of = dict(enumerate(centre_runs))
    index_of = {}
    for i in range(len(rows)):
        a, b = way_of_border[left[i]], way_of_border[right[i]]
        if a < 0 or b < 0:
            continue
        index_of[i] = len(laneletmap.lanelets)
        lanelet = {
            "left": int(a),
            "right": int(b),
            "forward": bool(forward[i]),
            "heading": float(heading[i]),
            "middle": middle_point[i],
            "tags": tags[i],
            "regulatory": [],
        }
        line = centre_of.get(i)
        if line is not None and len(line) >= 2:
            lanelet["centerline"] = len(laneletmap.way_nodes)
            laneletmap.way_nodes.append(line if forward[i] else line[::-1])
            laneletmap.way_tags.append({})
        laneletmap.lanelets.append(lanelet)
        laneletmap.lanelet_keys.append(keys[i])

    laneletmap.private_bounds, laneletmap.turned = give_private_bounds(laneletmap)

    _add_regulatory_elements(laneletmap, elements, element_points, node_of, index_of)
    _drop_unused_nodes(laneletmap)
    return laneletmap


def _drop_unused_nodes(laneletmap: LaneletMap) -> None:
    """Keep only the nodes some way holds, in their order: the samples that cutting folds and untangling
    dropped are no points of the map (a fifth of the sample build's nodes)."""
    used = np.zeros(len(laneletmap.nodes), dtype=bool)
    for nodes in laneletmap.way_nodes:  # a region's ways hold ten million node references: no copy of all
        used[nodes] = True
    if used.all():
        return
    renumbered = np.cumsum(used) - 1
    laneletmap.nodes = laneletmap.nodes[used]
    way_nodes = laneletmap.way_nodes
    for k, nodes in enumerate(way_nodes):
        way_nodes[k] = renumbered[nodes]


def _add_regulatory_elements(
    laneletmap: LaneletMap, elements, element_points, node_of: np.ndarray, index_of: dict[int, int]
) -> None:
    """Regulatory elements of the signals that govern written lanelets: a ``refers`` way for the signal, a
    ``ref_line`` stop line (one way for all signals with the same one)."""
    stop_lines: dict[tuple[int, ...], int] = {}
    for element, (refers, stop) in zip(elements, element_points):
        lanelets = [index_of[i] for i in element.lanelets if i in index_of]
        light = _dedup(node_of[refers])
        if not lanelets or len(light) < 2:
            continue
        members = [("way", len(laneletmap.way_nodes), "refers")]
        laneletmap.way_nodes.append(light)
        laneletmap.way_tags.append(element.refers_tags)
        line = _dedup(node_of[stop])
        if len(line) >= 2:
            key = tuple(int(n) for n in line)
            if key not in stop_lines:
                stop_lines[key] = len(laneletmap.way_nodes)
                laneletmap.way_nodes.append(line)
                laneletmap.way_tags.append({"type": "stop_line"})
            members.append(("way", stop_lines[key], "ref_line"))
        number = len(laneletmap.regulatory)
        laneletmap.regulatory.append({"tags": element.tags, "members": members})
        for i in lanelets:
            laneletmap.lanelets[i]["regulatory"].append(number)


def _select_lanes(odr, sampling, per_section: np.ndarray, section_first: np.ndarray):
    """(rows, lanelet tags, drives with s, (road index, section index, lane id), lanes too narrow) of the
    lanes that get a lanelet."""
    arrays = odr.arrays
    width = np.zeros(len(arrays.lane_id))
    np.maximum.at(width, sampling.pair_lane, np.abs(sampling.t_outer - sampling.t_inner))
    rows, tags, forward, keys = [], [], [], []
    narrow = 0
    # the lanes of the sampled sections (lane rows come section by section)
    sections = sampling.sample_section
    first = int(np.searchsorted(arrays.lane_section, sections[0], side="left")) if len(sections) else 0
    end = int(np.searchsorted(arrays.lane_section, sections[-1], side="right")) if len(sections) else 0
    for row in range(first, end):
        section_row = int(arrays.lane_section[row])
        if per_section[section_row] < 2:
            continue
        road_index = int(arrays.section_road[section_row])
        road = odr.roads[road_index]
        k = section_row - int(section_first[road_index])
        section = road.lane_sections[k]
        lane = section.by_id[int(arrays.lane_id[row])]
        road_type = road.type_at(section.s0)
        lane_tags = lanelet_tags(lane.type, None if road_type is None else road_type.type)
        if lane_tags is None:
            continue
        if width[row] < MIN_WIDTH:
            narrow += 1
            continue
        speed = lane_speed_limit(road, k, lane.id)
        if speed is not None and np.isfinite(speed) and speed > 0:
            lane_tags["speed_limit"] = f"{speed * 3.6:.6g} km/h"
        lane_tags.update(
            {
                "opendrive:road": road.id,
                "opendrive:lane_section": str(k),
                "opendrive:lane": str(lane.id),
                "opendrive:lane_type": lane.type,
            }
        )
        rows.append(row)
        tags.append(lane_tags)
        forward.append(drives_with_s(road, lane))
        keys.append((road_index, k, lane.id))
    return np.array(rows, dtype=np.int64), tags, np.array(forward, dtype=bool), keys, narrow


def _middles(sampling, rows: np.ndarray, forward: np.ndarray, per_section: np.ndarray):
    """(driving direction, (n, 3) lane-centre point) at the middle sample of each lane row's section (for
    ``orientation.give_private_bounds``)."""
    arrays = sampling.arrays
    section_start = np.searchsorted(sampling.sample_section, arrays.lane_section[rows], side="left")
    middle_sample = section_start + per_section[arrays.lane_section[rows]] // 2
    heading = sampling.heading[middle_sample] + np.where(forward, 0.0, np.pi)
    middle_pair = np.searchsorted(sampling.pair_lane, rows) + per_section[arrays.lane_section[rows]] // 2
    return heading, _centre_at(sampling, middle_pair)


def _centre_at(sampling, pairs: np.ndarray) -> np.ndarray:
    """(n, 3) lane-centre points of the given (lane, sample) pairs of a sampling."""
    sample = sampling.pair_sample[pairs]
    e_t, _ = surface_frame(sampling.heading[sample], sampling.slope[sample], sampling.superelevation[sample])
    t = 0.5 * (sampling.t_inner[pairs] + sampling.t_outer[pairs])
    reference = np.column_stack([sampling.ref_x[sample], sampling.ref_y[sample], sampling.ref_z[sample]])
    return reference + t[:, None] * e_t


def _dedup(nodes: np.ndarray) -> np.ndarray:
    keep = np.ones(len(nodes), dtype=bool)
    keep[1:] = nodes[1:] != nodes[:-1]
    return nodes[keep]


def _node_runs(
    first: np.ndarray, count: np.ndarray, node_of: np.ndarray, keep: np.ndarray
) -> list[np.ndarray]:
    """Node indices of each run of points (``first``, ``count``), without dropped points or repeats of one
    node in a row."""
    run = np.repeat(np.arange(len(first)), count)
    point = np.repeat(first - (np.cumsum(count) - count), count) + np.arange(int(count.sum()))
    run, point = run[keep[point]], point[keep[point]]
    nodes = node_of[point]
    fresh = np.ones(len(nodes), dtype=bool)
    fresh[1:] = (nodes[1:] != nodes[:-1]) | (run[1:] != run[:-1])
    return np.split(nodes[fresh], np.cumsum(np.bincount(run[fresh], minlength=len(first)))[:-1])


def _merge_groups(arrays, borders, centre, rows: np.ndarray, n_signal_points: int):
    """(group, shared) of every point for ``merge_points``: the group is the point's lane section (signal
    points are free); shared are the points of borders and centre lines that are no lane end (not the first
    or last point of one).

    Lanelet2 makes a lanelet the successor of another where both corners of its start are the nodes of the
    other's end, so only the links (``_link_joins``) may join lane ends of two sections. Points along the
    borders still become one node across sections where they coincide (the shared centre line of a two-way
    street that netconvert writes as two roads), but never with a lane end: through one, two unlinked lane
    ends could still end up one node."""
    section_of_border = np.concatenate([arrays.lane_section, np.arange(len(borders.start) - borders.n_lanes)])
    group = np.concatenate([
        section_of_border[borders.border],
        np.repeat(arrays.lane_section[rows], centre.count),
        np.full(n_signal_points, FREE),
    ]).astype(np.int32)
    n_border_points = len(borders.points)
    shared = np.ones(len(group), dtype=bool)
    shared[n_border_points + len(centre.points):] = False
    sampled = borders.count > 0
    for first, count in ((borders.start[sampled], borders.count[sampled]),
                         (n_border_points + centre.start, centre.count)):
        shared[first] = False
        shared[first + count - 1] = False
    return group, shared


def _link_joins(odr, borders, centre, lanelet_of: dict, row_of: dict, arrays) -> tuple[np.ndarray, int]:
    """(k, 2) point pairs to join: the corners of every pair of linked lane ends (matched by distance, since
    the inner border of one lane may meet the outer one of the next where a road's reference line changes
    side) and the ends of their centre lines (numbered after the border points), and how many linked pairs
    lay too far apart. Only these pairs make one node of points of two lane sections."""
    a_rows, a_end, b_rows, b_end, a_lanelet, b_lanelet = [], [], [], [], [], []
    for p, q in lane_end_pairs(odr):
        rp, rq = row_of.get(p[:3]), row_of.get(q[:3])
        if rp is None or rq is None:
            continue
        a_rows.append(rp)
        a_end.append(p[3] == "end")
        a_lanelet.append(lanelet_of[p[:3]])
        b_rows.append(rq)
        b_end.append(q[3] == "end")
        b_lanelet.append(lanelet_of[q[:3]])
    if not a_rows:
        return np.zeros((0, 2), dtype=np.int64), 0

    def corners(rows, at_end):
        rows, at_end = np.array(rows), np.array(at_end)
        inner, outer = borders.inner(rows, arrays), rows
        pick = lambda b: np.where(at_end, borders.last(b), borders.first(b))
        return pick(inner), pick(outer)

    a_in, a_out = corners(a_rows, a_end)
    b_in, b_out = corners(b_rows, b_end)
    points = borders.points

    def gap(i, j):
        return np.linalg.norm(points[i] - points[j], axis=1)

    same = np.maximum(gap(a_in, b_in), gap(a_out, b_out))
    crossed = np.maximum(gap(a_in, b_out), gap(a_out, b_in))
    swap = crossed < same
    b_first, b_second = np.where(swap, b_out, b_in), np.where(swap, b_in, b_out)
    ok = np.minimum(same, crossed) <= JOIN_TOLERANCE
    def centre_end(lanelets, at_end):
        lanelets = np.array(lanelets, dtype=np.int64)
        return len(points) + centre.start[lanelets] + np.where(at_end, centre.count[lanelets] - 1, 0)

    joins = np.concatenate([
        np.column_stack([a_in, b_first])[ok],
        np.column_stack([a_out, b_second])[ok],
        np.column_stack([centre_end(a_lanelet, a_end), centre_end(b_lanelet, b_end)])[ok],
    ])
    broken = {
        tuple(sorted(((r1, e1), (r2, e2))))
        for r1, e1, r2, e2, good in zip(a_rows, a_end, b_rows, b_end, ok)
        if not good
    }
    return joins, len(broken)


class _BorderMarks:
    """Line type of a border way from the road mark on it, plus lane_change tags where needed."""

    def __init__(self, odr, borders, section_first, rows, forward):
        self.odr, self.arrays, self.borders, self.section_first = odr, odr.arrays, borders, section_first
        self.outermost = outermost_rows(odr.arrays)
        self.position = {int(r): i for i, r in enumerate(rows)}
        self.forward = forward

    def tags(self, border: int) -> dict[str, str]:
        arrays, n_lanes = self.arrays, self.borders.n_lanes
        if border >= n_lanes:  # a section's centre line
            section_row, inner_row, outer_row, lane_id = border - n_lanes, None, None, 0
        else:
            section_row, inner_row, lane_id = (
                int(arrays.lane_section[border]),
                border,
                int(arrays.lane_id[border]),
            )
            outer_row = None if self.outermost[border] else border + 1
        road_index = int(arrays.section_road[section_row])
        road = self.odr.roads[road_index]
        k = section_row - int(self.section_first[road_index])
        section = road.lane_sections[k]
        middle = 0.5 * (section.s0 + road.section_end(k))
        lane = section.by_id.get(lane_id)
        mark = mark_at(lane, middle) if lane is not None else None
        beside = (1, -1) if lane_id == 0 else (lane_id, lane_id + int(np.sign(lane_id)))
        curb_beside = any((getattr(section.by_id.get(i), "type", "") or "").lower() == "curb" for i in beside)
        tags = line_tags(mark, lane_id <= 0, float(self.borders.raise_[border]), curb_beside)
        if inner_row is None or outer_row is None:
            return tags
        # between two same-direction vehicle lanes Lanelet2 must allow exactly the lane changes our graph does
        i, j = self.position.get(inner_row), self.position.get(outer_row)
        if i is None or j is None or self.forward[i] != self.forward[j]:
            return tags
        inner_lane = section.by_id[int(arrays.lane_id[inner_row])]
        outer_lane = section.by_id[int(arrays.lane_id[outer_row])]
        if not (is_vehicle_lane(inner_lane.type) and is_vehicle_lane(outer_lane.type)):
            return tags
        outward = lane_change_allowed(section, inner_lane.id, outer_lane.id, middle)
        inward = lane_change_allowed(section, outer_lane.id, inner_lane.id, middle)
        # the way runs with s: right-side lanes have the inner lane on its left, left-side lanes on its right
        wanted = (inward, outward) if inner_lane.id < 0 else (outward, inward)
        tags.update(lane_change_tags(wanted, tags))
        return tags
