"""Junctions (connections and lane links) and controllers."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True, slots=True)
class LaneLink:
    from_lane: int
    to_lane: int


@dataclass(frozen=True, slots=True)
class Connection:
    id: str
    incoming_road: str
    connecting_road: str
    contact_point: str = "start"
    lane_links: tuple[LaneLink, ...] = ()
    attrib: dict = field(default_factory=dict, compare=False)
    extra_xml: tuple[bytes, ...] = field(default=(), compare=False)


@dataclass(frozen=True, slots=True)
class JunctionController:
    id: str
    type: str | None = None
    sequence: int | None = None


@dataclass(frozen=True, slots=True)
class Junction:
    id: str
    name: str = ""
    type: str = "default"
    connections: tuple[Connection, ...] = ()
    controllers: tuple[JunctionController, ...] = ()
    line: int | None = field(default=None, compare=False)
    attrib: dict = field(default_factory=dict, compare=False)
    extra_xml: tuple[bytes, ...] = field(default=(), compare=False)


@dataclass(frozen=True, slots=True)
class Controller:
    id: str
    name: str = ""
    sequence: int | None = None
    signal_ids: tuple[str, ...] = ()
    attrib: dict = field(default_factory=dict, compare=False)
    extra_xml: tuple[bytes, ...] = field(default=(), compare=False)
