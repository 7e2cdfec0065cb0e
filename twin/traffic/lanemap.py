"""Place SUMO vehicles inside junctions on the OpenDRIVE connecting lanes, not on SUMO's internal lanes.

netconvert writes one network twice, and the two agree exactly on ordinary lanes but not inside junctions:
a SUMO internal lane keeps its own shape (on DLR's TAVF network often a straight line edited in netedit),
while the OpenDRIVE connecting road is a smooth curve from the incoming to the outgoing lane. They share
their end points but part by up to 5 m in between (20 % of TAVF's internal-lane length is more than 0.5 m
off). The twin's world -- road surface, collision mesh, the ego's own lanes -- is the OpenDRIVE one, so a car
crossing a junction is placed at the same fraction of its way along the matching OpenDRIVE lane.

Matching is geometric: a chain of SUMO internal lanes (from an incoming to an outgoing lane) and an
OpenDRIVE lane of a junction road match when their start points and their end points each lie within
``MATCH_TOLERANCE_M``. Chains without a match keep SUMO's own position (counted in ``unmatched``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from tavf_mapkit.opendrive.borders import border_offsets

MATCH_TOLERANCE_M = 0.6
SAMPLE_STEP_M = 0.25  # chord error on a 5 m junction radius: 1.6 mm
KEY_SPAN = 0.999  # fractions 0..1 of line k map to keys k..k+0.999, so lines never interleave


@dataclass(frozen=True, eq=False)
class JunctionLaneMap:
    """SUMO internal lane id -> a place on a densely sampled OpenDRIVE connecting-lane centre line."""

    piece: dict[str, tuple[int, float, float]]  # internal lane -> (polyline index, fraction at its start, per metre)
    key: np.ndarray  # polyline index + arc-length fraction * KEY_SPAN, ascending: one searchsorted for all
    points: np.ndarray  # (m, 3) centre-line samples in travel direction
    matched_chains: int
    unmatched_chains: int

    @classmethod
    def build(cls, odr, frame, sumo_api) -> JunctionLaneMap:
        chains = _internal_chains(sumo_api)
        rows, starts, ends = _junction_lane_ends(odr)
        piece: dict[str, tuple[int, float, float]] = {}
        polyline_of_row: dict[int, int] = {}
        matched = 0
        if chains and len(rows):
            tree = cKDTree(starts)
            chain_start = np.array([c[1] for c in chains])
            chain_end = np.array([c[2] for c in chains])
            sx, sy = frame.net_to_local(chain_start[:, 0], chain_start[:, 1])
            ex, ey = frame.net_to_local(chain_end[:, 0], chain_end[:, 1])
            for (pieces, _s, _e, lengths), start, end in zip(chains, np.column_stack([sx, sy]),
                                                             np.column_stack([ex, ey])):
                candidates = tree.query_ball_point(start, MATCH_TOLERANCE_M)
                if not candidates:
                    continue
                miss = np.hypot(*(ends[candidates] - end).T)
                best = int(np.argmin(miss))
                if miss[best] > MATCH_TOLERANCE_M:
                    continue
                matched += 1
                row = int(rows[candidates[best]])
                polyline = polyline_of_row.setdefault(row, len(polyline_of_row))
                total = float(sum(lengths)) or 1.0
                done = 0.0
                for name, length in zip(pieces, lengths):
                    piece[name] = (polyline, done / total, 1.0 / total)
                    done += length
        key, points = _sample_polylines(odr.arrays, list(polyline_of_row))
        return cls(piece, key, points, matched, len(chains) - matched)

    def place(self, lane_ids, lane_positions) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(mapped, x, y, z, yaw) for vehicles on these SUMO lanes at these lane positions (metres)."""
        n = len(lane_ids)
        mapped = np.array([lane in self.piece for lane in lane_ids], dtype=bool)
        x, y, z, yaw = (np.zeros(n) for _ in range(4))
        if not mapped.any():
            return mapped, x, y, z, yaw
        info = np.array([self.piece[lane] for lane, m in zip(lane_ids, mapped) if m], dtype=float).reshape(-1, 3)
        fraction = np.clip(info[:, 1] + np.asarray(lane_positions, dtype=float)[mapped] * info[:, 2], 0.0, 1.0)
        wanted = info[:, 0] + fraction * KEY_SPAN
        after = np.clip(np.searchsorted(self.key, wanted, side="right"), 1, len(self.key) - 1)
        before = after - 1
        same_line = np.floor(self.key[after]) == np.floor(self.key[before])
        after = np.where(same_line, after, before)  # at the very end of a line: stay on it
        before = np.where(same_line, before, before - 1)
        span = self.key[after] - self.key[before]
        weight = np.clip(np.where(span > 0, (wanted - self.key[before]) / np.where(span > 0, span, 1.0), 0.0), 0, 1)
        point = self.points[before] + weight[:, None] * (self.points[after] - self.points[before])
        direction = self.points[after] - self.points[before]
        x[mapped], y[mapped], z[mapped] = point[:, 0], point[:, 1], point[:, 2]
        yaw[mapped] = np.arctan2(direction[:, 1], direction[:, 0])
        return mapped, x, y, z, yaw


def _sample_polylines(arrays, rows: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """Centre lines of lane-table ``rows`` every <= SAMPLE_STEP_M, keyed by index + arc-length fraction."""
    if not rows:
        return np.array([0.0, 0.5]), np.zeros((2, 3))
    rows_array = np.array(rows, dtype=np.int64)
    section = arrays.lane_section[rows_array]
    s0, s1 = arrays.section_s0[section], arrays.section_end[section]
    count = np.maximum(2.0, np.ceil((s1 - s0) / SAMPLE_STEP_M) + 1)
    arrays.budget.check(arrays.section_road[section], count, f"lane centre lines every {SAMPLE_STEP_M:g} m")
    count = count.astype(int)
    owner = np.repeat(np.arange(len(rows)), count)
    first = np.repeat(np.cumsum(count) - count, count)
    u = (np.arange(len(owner)) - first) / np.repeat(count - 1, count)  # 0..1 along each lane
    # right lanes run along s, left ones against it: netconvert's OpenDRIVE (the only kind with a SUMO network)
    # has no rule="LHT"; in a left-hand network too it writes each direction as right lanes along s
    forward = np.repeat(arrays.lane_id[rows_array] < 0, count)
    s = np.where(forward, np.repeat(s0, count) + u * np.repeat(s1 - s0, count),
                 np.repeat(s1, count) - u * np.repeat(s1 - s0, count))
    x, y, z = _lane_centre(arrays, arrays.section_road[np.repeat(section, count)], np.repeat(rows_array, count), s)
    points = np.column_stack([x, y, z])
    step = np.r_[0.0, np.hypot(np.diff(x), np.diff(y))]
    step[np.r_[True, owner[1:] != owner[:-1]]] = 0.0  # each line starts at 0
    along = np.cumsum(step)
    along -= np.repeat(along[np.cumsum(count) - count], count)
    length = np.repeat(along[np.cumsum(count) - 1], count)
    fraction = np.where(length > 0, along / np.where(length > 0, length, 1.0), u)
    return owner + fraction * KEY_SPAN, points


def _lane_centre(arrays, road, row, s):
    rx, ry, rz, heading, *_ = arrays.reference(road, s)
    t_inner, t_outer = border_offsets(arrays, row, s)
    t = 0.5 * (t_inner + t_outer)
    return rx - t * np.sin(heading), ry + t * np.cos(heading), rz


def _internal_chains(sumo_api) -> list[tuple[list[str], tuple, tuple, list[float]]]:
    """(internal lanes, start point, end point, piece lengths) of every connection through a junction."""
    chains = []
    for lane in sumo_api.lane.getIDList():
        if lane.startswith(":"):
            continue
        for link in sumo_api.lane.getLinks(lane):
            via = link[4]
            if not via:
                continue
            pieces = [via]
            while len(pieces) < 8:
                following = sumo_api.lane.getLinks(pieces[-1])
                if len(following) != 1 or not following[0][0].startswith(":"):
                    break
                pieces.append(following[0][0])
            first, last = sumo_api.lane.getShape(pieces[0]), sumo_api.lane.getShape(pieces[-1])
            chains.append((pieces, first[0], last[-1], [sumo_api.lane.getLength(p) for p in pieces]))
    return chains


def _junction_lane_ends(odr) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Lane table rows of the junction roads' lanes and their centre start/end points in travel direction."""
    arrays = odr.arrays
    in_junction = np.array([road.in_junction for road in odr.roads], dtype=bool)
    road_of_row = arrays.section_road[arrays.lane_section]
    rows = np.flatnonzero(in_junction[road_of_row] & (arrays.lane_type != "sidewalk"))
    if not len(rows):
        return rows, np.empty((0, 2)), np.empty((0, 2))
    section = arrays.lane_section[rows]
    road = arrays.section_road[section]
    s0, s1 = arrays.section_s0[section], arrays.section_end[section]
    ax, ay, _ = _lane_centre(arrays, road, rows, s0)
    bx, by, _ = _lane_centre(arrays, road, rows, s1)
    forward = arrays.lane_id[rows] < 0
    starts = np.where(forward[:, None], np.column_stack([ax, ay]), np.column_stack([bx, by]))
    ends = np.where(forward[:, None], np.column_stack([bx, by]), np.column_stack([ax, ay]))
    return rows, starts, ends
