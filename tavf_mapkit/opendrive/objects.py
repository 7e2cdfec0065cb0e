"""Road objects (with repeat and outline), signals and signal references."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class OutlineCorner:
    kind: str  # "cornerLocal" or "cornerRoad"
    a: float  # u (local) or s (road)
    b: float  # v (local) or t (road)
    z: float  # z (local) or dz (road)
    height: float
    attrib: dict = field(default_factory=dict, compare=False)


@dataclass(frozen=True)
class Outline:
    corners: tuple[OutlineCorner, ...]
    closed: bool = True
    attrib: dict = field(default_factory=dict, compare=False)


@dataclass(frozen=True)
class ObjectRepeat:
    s: float
    length: float
    distance: float
    t_start: float
    t_end: float
    z_offset_start: float = 0.0
    z_offset_end: float = 0.0
    height_start: float | None = None
    height_end: float | None = None
    width_start: float | None = None
    width_end: float | None = None
    length_start: float | None = None
    length_end: float | None = None
    radius_start: float | None = None
    radius_end: float | None = None
    attrib: dict = field(default_factory=dict, compare=False)


@dataclass(frozen=True)
class RoadObject:
    id: str
    s: float
    t: float
    type: str = "none"
    name: str = ""
    z_offset: float = 0.0
    hdg: float = 0.0
    pitch: float = 0.0
    roll: float = 0.0
    length: float | None = None
    width: float | None = None
    height: float | None = None
    radius: float | None = None
    orientation: str = "none"
    repeats: tuple[ObjectRepeat, ...] = ()
    outlines: tuple[Outline, ...] = ()
    line: int | None = field(default=None, compare=False)
    attrib: dict = field(default_factory=dict, compare=False)
    extra_xml: tuple[bytes, ...] = field(default=(), compare=False)


@dataclass(frozen=True)
class Signal:
    id: str
    s: float
    t: float
    dynamic: bool = False
    orientation: str = "+"
    z_offset: float = 0.0
    country: str | None = None
    type: str = "-1"
    subtype: str = "-1"
    value: float | None = None
    unit: str | None = None
    name: str = ""
    height: float | None = None
    width: float | None = None
    h_offset: float = 0.0
    pitch: float = 0.0
    roll: float = 0.0
    line: int | None = field(default=None, compare=False)
    attrib: dict = field(default_factory=dict, compare=False)
    extra_xml: tuple[bytes, ...] = field(default=(), compare=False)


@dataclass(frozen=True)
class SignalReference:
    id: str
    s: float
    t: float
    orientation: str = "+"
    attrib: dict = field(default_factory=dict, compare=False)
    extra_xml: tuple[bytes, ...] = field(default=(), compare=False)
