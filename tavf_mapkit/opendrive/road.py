"""Roads: reference line, elevation and lateral profiles, lane offset, lane sections, objects and signals."""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from tavf_mapkit.opendrive.cubic import EMPTY_PROFILE, CubicProfile
from tavf_mapkit.opendrive.lanesection import LaneSection
from tavf_mapkit.opendrive.objects import RoadObject, Signal, SignalReference
from tavf_mapkit.opendrive.refline import ReferenceLine
from tavf_mapkit.opendrive.surface import surface_points


@dataclass(frozen=True, slots=True)
class RoadLink:
    element_type: str  # "road" or "junction"
    element_id: str
    contact_point: str | None = None  # "start" / "end" for roads
    attrib: dict = field(default_factory=dict, compare=False)


@dataclass(frozen=True, slots=True)
class RoadType:
    s0: float
    type: str
    country: str | None = None
    speed_max: float | None = None  # m/s, None when absent or "no limit"
    attrib: dict = field(default_factory=dict, compare=False)
    speed_attrib: dict | None = field(default=None, compare=False)


@dataclass(frozen=True, slots=True)
class ShapeRecord:
    s0: float
    t: float
    coefficients: tuple[float, float, float, float]


@dataclass(frozen=True, eq=False)
class Road:
    id: str
    length: float
    reference_line: ReferenceLine
    lane_sections: tuple[LaneSection, ...]
    junction: str = "-1"
    name: str = ""
    rule: str = "RHT"
    predecessor: RoadLink | None = None
    successor: RoadLink | None = None
    types: tuple[RoadType, ...] = ()
    elevation: CubicProfile = EMPTY_PROFILE
    superelevation: CubicProfile = EMPTY_PROFILE
    shape: tuple[ShapeRecord, ...] = ()
    lane_offset: CubicProfile = EMPTY_PROFILE
    objects: tuple[RoadObject, ...] = ()
    signals: tuple[Signal, ...] = ()
    signal_references: tuple[SignalReference, ...] = ()
    line: int | None = field(default=None, compare=False)
    attrib: dict = field(default_factory=dict, compare=False)
    extra_xml: dict = field(default_factory=dict, compare=False)  # parent tag -> tuple of unknown children

    @property
    def in_junction(self) -> bool:
        return self.junction not in ("-1", "", None)

    @cached_property
    def section_starts(self) -> np.ndarray:
        return np.array([section.s0 for section in self.lane_sections])

    def section_end(self, index: int) -> float:
        return self.lane_sections[index + 1].s0 if index + 1 < len(self.lane_sections) else self.length

    def section_index(self, s) -> np.ndarray:
        """Index of the lane section that governs each s (the last section starting at or before s)."""
        return np.clip(np.searchsorted(self.section_starts, s, side="right") - 1, 0, len(self.lane_sections) - 1)

    def reference_point(self, s):
        """(x, y, z, heading, slope, superelevation) at each s."""
        s = np.atleast_1d(np.asarray(s, dtype=float))
        x, y, heading, _ = self.reference_line.evaluate(s)
        return x, y, self.elevation(s), heading, self.elevation.derivative(s), self.superelevation(s)

    def surface_point(self, s, t, h=None) -> np.ndarray:
        """(n, 3) points at road coordinates (s, t, h) -- the exact surface, no lane height applied."""
        s = np.atleast_1d(np.asarray(s, dtype=float))
        t = np.broadcast_to(np.asarray(t, dtype=float), s.shape)
        x, y, z, heading, slope, roll = self.reference_point(s)
        return surface_points(x, y, z, heading, slope, roll, t, None if h is None else np.broadcast_to(h, s.shape))

    def lane_borders(self, section_index: int, s) -> dict[int, np.ndarray]:
        """t of the outer border of every lane of a section at each s (lane 0: the lane offset)."""
        s = np.atleast_1d(np.asarray(s, dtype=float))
        # at the section's own end, a laneOffset record starting there is not yet in force (see
        # NetworkArrays.section_lane_offset): evaluate a hair before it
        at_end = s >= self.section_end(section_index) - 1e-9
        offset = self.lane_offset(np.where(at_end, np.nextafter(s, -np.inf), s))
        return self.lane_sections[section_index].outer_borders(s, offset)

    def lane_border_points(self, section_index: int, lane_id: int, s) -> np.ndarray:
        """(n, 3) points of a lane's outer border."""
        s = np.atleast_1d(np.asarray(s, dtype=float))
        t = self.lane_borders(section_index, s)[lane_id]
        return self.surface_point(s, t)

    def type_at(self, s: float) -> RoadType | None:
        """The road type record in force at s (the last one starting at or before it), None before the first."""
        found = None
        for road_type in self.types:
            if road_type.s0 <= s + 1e-9:
                found = road_type
        return found

    def speed_limit(self, s: float) -> float | None:
        """Speed limit of the road type record at s in m/s (None if none is set)."""
        road_type = self.type_at(s)
        return None if road_type is None else road_type.speed_max
