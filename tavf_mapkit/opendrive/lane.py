"""Lanes: id, type, level, links, width or border records, height, road marks, speed, access, material."""

from __future__ import annotations

from dataclasses import dataclass, field

from tavf_mapkit.opendrive.cubic import EMPTY_PROFILE, CubicProfile


@dataclass(frozen=True, slots=True)
class RoadMarkLine:
    """An explicit or type ``<line>`` of a road mark (lengths in m)."""

    length: float = 0.0
    space: float = 0.0
    t_offset: float = 0.0
    s_offset: float = 0.0
    width: float | None = None
    rule: str | None = None
    color: str | None = None
    attrib: dict = field(default_factory=dict, compare=False)


@dataclass(frozen=True, slots=True)
class RoadMark:
    s_offset: float
    type: str = "none"
    weight: str | None = None
    color: str = "standard"
    width: float | None = None
    lane_change: str | None = None
    height: float | None = None
    material: str | None = None
    type_name: str | None = None
    type_width: float | None = None
    lines: tuple[RoadMarkLine, ...] = ()
    explicit: bool = False
    attrib: dict = field(default_factory=dict, compare=False)
    extra_xml: tuple[bytes, ...] = field(default=(), compare=False)


@dataclass(frozen=True, slots=True)
class LaneHeight:
    s0: float  # absolute road s
    inner: float
    outer: float


@dataclass(frozen=True, slots=True)
class LaneRecord:
    """speed, access or material records of a lane: kept as attributes (sOffset made absolute in s0)."""

    tag: str
    s0: float
    attrib: dict = field(compare=False)
    extra_xml: tuple[bytes, ...] = field(default=(), compare=False)


@dataclass(frozen=True, slots=True)
class Lane:
    id: int
    type: str = "driving"
    level: bool = False
    predecessor: int | None = None
    successor: int | None = None
    widths: CubicProfile = EMPTY_PROFILE  # s0 absolute (section s0 + sOffset)
    borders: CubicProfile = EMPTY_PROFILE
    heights: tuple[LaneHeight, ...] = ()
    road_marks: tuple[RoadMark, ...] = ()
    records: tuple[LaneRecord, ...] = ()
    line: int | None = field(default=None, compare=False)
    attrib: dict = field(default_factory=dict, compare=False)
    extra_xml: tuple[bytes, ...] = field(default=(), compare=False)

    @property
    def uses_border(self) -> bool:
        """Width records win over border records when both are present (ASAM OpenDRIVE)."""
        return not len(self.widths) and bool(len(self.borders))

    @property
    def side(self) -> int:
        return (self.id > 0) - (self.id < 0)

    def speed_limits(self) -> list[tuple[float, float]]:
        """(s0, m/s) of the lane's speed records."""
        out = []
        for record in self.records:
            if record.tag == "speed" and "max" in record.attrib:
                from tavf_mapkit.opendrive.units import speed_to_mps

                value = speed_to_mps(record.attrib.get("max"), record.attrib.get("unit"))
                if value is not None:
                    out.append((record.s0, value))
        return out
