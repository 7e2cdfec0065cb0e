"""The whole map flattened into tables, so that sampling every lane of every road is a few numpy calls.

Lookups across roads find the governing record of every sample of every road at once: each query's group (road
or lane row index) gives its records' rows, and a binary search in s inside them, all queries together, is exact.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from tavf_mapkit.opendrive.budget import SampleBudget
from tavf_mapkit.opendrive.cubic import CubicProfile
from tavf_mapkit.opendrive.geometry import GeometryTable
from tavf_mapkit.opendrive.refline import gather_rows, gather_side


@dataclass(frozen=True, eq=False)
class RecordTable:
    """Cubic records of many groups (roads or lanes): key-sorted, with a per-record 'extend before first' flag."""

    group: np.ndarray
    s0: np.ndarray
    coefficients: np.ndarray
    span: float
    extend_first: bool

    @property
    def group_bounds(self) -> np.ndarray:
        """Where each group's records start in the table, for groups 0 .. the last one with records (and the
        table's end after it): a query's group finds its records by two lookups, not a search of the table."""
        bounds = self.__dict__.get("_group_bounds")
        if bounds is None:
            groups = int(self.group[-1]) + 1 if len(self.group) else 0
            bounds = np.searchsorted(self.group, np.arange(groups + 1), side="left")
            object.__setattr__(self, "_group_bounds", bounds)
        return bounds

    def _last_at_or_before(self, group: np.ndarray, s: np.ndarray, inclusive: bool) -> np.ndarray:
        """Row of the table's last record whose (group, s0) is at or before (``inclusive``) or strictly before
        (group, s), -1 if none: exact in s, by a binary search inside each query's group (all queries at once;
        most groups hold one or two records). The same rows a search of keys ``group + i*s0`` finds, where
        complex numbers order lexicographically (what this table searched until a region's sampling spent a
        tenth of its time comparing complex keys); for a non-finite s those keys were NaN + i*s, past every key
        seen from the right and before every key seen from the left, so such an s finds the table's last
        record (``inclusive``) or none."""
        bounds = self.group_bounds
        top = len(bounds) - 1
        low = bounds[np.clip(group, 0, top)]
        high = bounds[np.clip(group + 1, 0, top)]
        finite = np.isfinite(s)
        # invariant: records [group's first, low) are before s, [high, group's end) are not
        open_ = np.flatnonzero(finite & (low < high))
        while len(open_):
            at, end, query = low[open_], high[open_], s[open_]
            middle = (at + end) >> 1
            value = self.s0[middle]
            before = value <= query if inclusive else value < query
            low[open_] = np.where(before, middle + 1, at)
            high[open_] = np.where(before, end, middle)
            open_ = open_[low[open_] < high[open_]]
        index = low - 1
        if not finite.all():
            index[~finite] = len(self.s0) - 1 if inclusive else -1
        return index

    @staticmethod
    def build(profiles: list[CubicProfile], span: float, extend_first: bool = False) -> RecordTable:
        counts = np.array([len(p) for p in profiles], dtype=np.int64)
        group = np.repeat(np.arange(len(profiles)), counts)
        nonempty = [p for p in profiles if len(p)]
        s0 = np.concatenate([p.s0 for p in nonempty]) if nonempty else np.zeros(0)
        coefficients = np.concatenate([p.coefficients for p in nonempty]) if nonempty else np.zeros((0, 4))
        return RecordTable(group, s0, coefficients, span, extend_first)

    def intervals(self, group_end: np.ndarray) -> np.ndarray:
        """Length of each record's interval: to the next record of its group, the last one to ``group_end[group]``."""
        group, s0 = self.group, self.s0
        nxt = np.empty_like(s0)
        if len(s0):
            nxt[:-1] = s0[1:]
            last = np.ones(len(s0), dtype=bool)
            last[:-1] = group[1:] != group[:-1]
            nxt[last] = group_end[group[last]]
        return nxt - s0

    def evaluate(self, group: np.ndarray, s: np.ndarray, derivative: bool = False,
                 from_left: np.ndarray | None = None) -> np.ndarray:
        """Values at (group, s). Where ``from_left`` is True, a record that starts exactly at s is not yet in
        force (the limit from the left: the value at the end of the interval before s)."""
        if not len(self.s0):
            return np.zeros(len(s))
        group, s = np.asarray(group, dtype=np.int64), np.asarray(s, dtype=float)
        return self._cubic(*self._rows(group, s, from_left), s, derivative)

    def evaluate_with_derivative(self, group: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(``evaluate(group, s)``, ``evaluate(group, s, derivative=True)``), the records found once."""
        if not len(self.s0):
            return np.zeros(len(s)), np.zeros(len(s))
        group, s = np.asarray(group, dtype=np.int64), np.asarray(s, dtype=float)
        rows = self._rows(group, s, None)
        return self._cubic(*rows, s, False), self._cubic(*rows, s, True)

    def _rows(self, group: np.ndarray, s: np.ndarray, from_left) -> tuple[np.ndarray, np.ndarray]:
        """(row of the record in force at each (group, s), clipped into the table; whether there is one)."""
        index = self._last_at_or_before(group, s, inclusive=True)
        if from_left is not None:
            # only the queries asking for the limit from the left (a section's end: a few of its samples)
            left = np.flatnonzero(np.asarray(from_left, dtype=bool))
            before = self._last_at_or_before(group[left], s[left], inclusive=False)
            # only inside the group: at the group's first record there is nothing to its left
            same = (before >= 0) & (self.group[np.maximum(before, 0)] == group[left])
            index[left[same]] = before[same]
        if self.extend_first:
            # before a group's first record: use that first record
            bounds = self.group_bounds
            first = bounds[np.clip(group, 0, len(bounds) - 1)]
            index = np.where((index < first) & (first < len(self.group)), first, index)
        i = np.clip(index, 0, len(self.s0) - 1)
        return i, (index >= 0) & (self.group[i] == group)

    def _cubic(self, i: np.ndarray, valid: np.ndarray, s: np.ndarray, derivative: bool) -> np.ndarray:
        ds = s - self.s0[i]
        a, b, c, d = self.coefficients[i].T
        value = b + ds * (2.0 * c + 3.0 * d * ds) if derivative else a + ds * (b + ds * (c + ds * d))
        return np.where(valid, value, 0.0)


def _step_profile(records: list[tuple[float, float]]) -> CubicProfile:
    """Lane height records are constant until the next one: a cubic with only the constant term."""
    return CubicProfile.from_records([(s0, value, 0.0, 0.0, 0.0) for s0, value in records])


@dataclass(frozen=True, eq=False)
class NetworkArrays:
    geometries: GeometryTable
    elevation: RecordTable
    superelevation: RecordTable
    lane_offset: RecordTable
    road_length: np.ndarray
    span: float
    # lane sections
    section_road: np.ndarray
    section_s0: np.ndarray
    section_end: np.ndarray
    # side lanes (every lane except 0), ordered by section, side (left first), |id|
    lane_section: np.ndarray
    lane_id: np.ndarray
    lane_rank: np.ndarray  # 0 for the lane next to the centre, 1 for the next, ...
    lane_uses_border: np.ndarray
    lane_type: np.ndarray  # object array of type strings
    lane_width: RecordTable
    lane_border: RecordTable
    lane_height_inner: RecordTable
    lane_height_outer: RecordTable
    budget: SampleBudget | None = None  # what sampling this map may allocate (ask before allocating)

    @staticmethod
    def build(odr) -> NetworkArrays:
        roads = odr.roads
        lengths = np.array([road.length for road in roads], dtype=float)
        span = float(max(lengths.max(initial=0.0), 1.0) * 2.0 + 10.0)
        counts = np.array([len(road.reference_line) for road in roads], dtype=np.int64)
        # one table the roads' reference lines then hold views of (never two copies of a city's 5 million rows)
        rows = gather_rows(road.reference_line for road in roads)
        side_index, side_params = gather_side([road.reference_line for road in roads], counts)
        table = GeometryTable.from_rows(rows, np.repeat(np.arange(len(roads), dtype=np.int64), counts),
                                        side_index, side_params)
        section_road, section_s0, section_end = [], [], []
        lane_section, lane_id, lane_rank, lane_border_flag, lane_type, widths, borders = [], [], [], [], [], [], []
        heights_inner, heights_outer = [], []
        for road_index, road in enumerate(roads):
            for k, section in enumerate(road.lane_sections):
                section_index = len(section_s0)
                section_road.append(road_index)
                section_s0.append(section.s0)
                section_end.append(road.section_end(k))
                for side_lanes in (section.left, section.right):
                    for rank, lane in enumerate(side_lanes):
                        lane_section.append(section_index)
                        lane_id.append(lane.id)
                        lane_rank.append(rank)
                        lane_border_flag.append(lane.uses_border)
                        lane_type.append(lane.type)
                        widths.append(lane.widths)
                        borders.append(lane.borders)
                        heights_inner.append(_step_profile([(h.s0, h.inner) for h in lane.heights]))
                        heights_outer.append(_step_profile([(h.s0, h.outer) for h in lane.heights]))
        arrays = NetworkArrays(
            geometries=table,
            elevation=RecordTable.build([r.elevation for r in roads], span),
            superelevation=RecordTable.build([r.superelevation for r in roads], span),
            lane_offset=RecordTable.build([r.lane_offset for r in roads], span),
            road_length=lengths,
            span=span,
            section_road=np.array(section_road, dtype=np.int64),
            section_s0=np.array(section_s0, dtype=float),
            section_end=np.array(section_end, dtype=float),
            lane_section=np.array(lane_section, dtype=np.int64),
            lane_id=np.array(lane_id, dtype=np.int64),
            lane_rank=np.array(lane_rank, dtype=np.int64),
            lane_uses_border=np.array(lane_border_flag, dtype=bool),
            lane_type=np.array(lane_type, dtype=object),
            lane_width=RecordTable.build(widths, span, extend_first=True),
            lane_border=RecordTable.build(borders, span, extend_first=True),
            lane_height_inner=RecordTable.build(heights_inner, span),
            lane_height_outer=RecordTable.build(heights_outer, span),
        )
        return replace(arrays, budget=SampleBudget.build(odr, arrays))

    def section_lane_offset(self, section: np.ndarray, s: np.ndarray) -> np.ndarray:
        """laneOffset as the lane sections see it: at a section's own end, the record in force inside the
        section, not one that starts there (CARLA's maps step laneOffset exactly at section boundaries, by as
        much as the lanes that appear beside it are wide, so the lanes themselves do not move)."""
        section = np.asarray(section, dtype=np.int64)
        s = np.asarray(s, dtype=float)
        at_end = s >= self.section_end[section] - 1e-9
        return self.lane_offset.evaluate(self.section_road[section], s, from_left=at_end)

    def reference(self, road: np.ndarray, s: np.ndarray):
        """(x, y, z, heading, slope, superelevation, lane_offset) for arrays of (road index, s)."""
        return (*self.pose(road, s), self.lane_offset.evaluate(road, s))

    def pose(self, road: np.ndarray, s: np.ndarray):
        """(x, y, z, heading, slope, superelevation) of the reference line for arrays of (road index, s):
        ``reference`` without the lane offset (lane sections read theirs at their own ends: a sampling asks
        ``section_lane_offset``)."""
        n = len(s)
        if len(self.geometries):
            # the rule ReferenceLine uses too: before a road's first geometry, that first one
            index, has = self.geometries.locate(road, s)
            x, y, heading, _ = self.geometries.evaluate(index, s - self.geometries.s[index])
            x, y, heading = (np.where(has, v, 0.0) for v in (x, y, heading))
        else:
            x = y = heading = np.zeros(n)
        z, slope = self.elevation.evaluate_with_derivative(road, s)
        return x, y, z, heading, slope, self.superelevation.evaluate(road, s)
