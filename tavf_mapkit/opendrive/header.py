"""The OpenDRIVE header: version, name, bounds, vendor, geoReference and offset."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class Offset:
    """Header ``<offset>``: projected = (x, y, z) + R(hdg) * local (see georef.py for why this sign)."""

    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    hdg: float = 0.0


@dataclass(frozen=True)
class Header:
    rev_major: int = 1
    rev_minor: int = 4
    name: str = ""
    version: str | None = None
    date: str | None = None
    north: float = 0.0
    south: float = 0.0
    east: float = 0.0
    west: float = 0.0
    vendor: str | None = None
    geo_reference: str | None = None
    offset: Offset | None = None
    line: int | None = field(default=None, compare=False)
    attrib: dict = field(default_factory=dict, compare=False)
    extra_xml: tuple[bytes, ...] = field(default=(), compare=False)

    @property
    def revision(self) -> str:
        return f"{self.rev_major}.{self.rev_minor}"
