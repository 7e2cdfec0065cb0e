"""SUMO network input (.net.xml, .net.xml.gz): a safety check before netconvert reads it; its georeference.

netconvert parses a SUMO network with its own XML parser, so the checks happen here first: the file must
be well-formed, have a <net> root and carry no DOCTYPE (a SUMO network never has one; a DOCTYPE is how
external entities and external DTDs get in).
"""

from __future__ import annotations

import gzip
import re
import zlib
from dataclasses import dataclass
from pathlib import Path

from tavf_mapkit.errors import InputError

SUMO_NET_SUFFIXES = (".net.xml", ".net.xml.gz")
_DOCTYPE = re.compile(rb"<!DOCTYPE", re.IGNORECASE)


def is_sumo_net(path: str | Path) -> bool:
    return str(path).lower().endswith(SUMO_NET_SUFFIXES)


@dataclass(frozen=True)
class Location:
    """A SUMO network's <location>: net = projected + net_offset; ``proj`` "!" = not georeferenced."""

    net_offset: tuple[float, float]
    conv_boundary: tuple[float, float, float, float]
    orig_boundary: tuple[float, float, float, float]
    proj: str

    @property
    def georeferenced(self) -> bool:
        return bool(self.proj) and self.proj != "!"

    def to_dict(self) -> dict:
        return {"netOffset": list(self.net_offset), "convBoundary": list(self.conv_boundary),
                "origBoundary": list(self.orig_boundary), "projParameter": self.proj}

    def centre_wgs84(self) -> tuple[float, float] | None:
        """(lon, lat) of the middle of the network's extent; None when it is not georeferenced."""
        if not self.georeferenced:
            return None
        import pyproj

        west, south, east, north = self.conv_boundary
        x = 0.5 * (west + east) - self.net_offset[0]  # net = projected + netOffset
        y = 0.5 * (south + north) - self.net_offset[1]
        try:
            lon, lat = pyproj.Proj(self.proj)(x, y, inverse=True)
        except (pyproj.exceptions.CRSError, ValueError):
            return None
        return (round(lon, 7), round(lat, 7)) if abs(lon) <= 180 and abs(lat) <= 90 else None


def read_net_bytes(path: str | Path) -> bytes:
    """The uncompressed XML of a SUMO network; unreadable or corrupt files become InputErrors."""
    from tavf_mapkit.xmlsafe import read_input_bytes

    name = str(path)
    raw = read_input_bytes(path, "a SUMO network file")
    if raw[:2] == b"\x1f\x8b":
        try:
            return gzip.decompress(raw)
        except (OSError, EOFError, zlib.error) as error:
            raise InputError(f"cannot decompress gzip ({error or 'truncated'})", file=name) from None
    return raw


def check_sumo_net(path: str | Path) -> dict:
    """Refuse a SUMO network netconvert should not read; return its counts and <location>."""
    from tavf_mapkit.xmlsafe import iterparse_safe, prepare_xml_bytes, release_if_top_level

    name = str(path)
    source = prepare_xml_bytes(read_net_bytes(path), name)
    doctype = _DOCTYPE.search(source.data[:1 << 16])
    if doctype:
        line = source.data[:doctype.start()].count(b"\n") + 1 + source.line_offset
        raise InputError("refused: a SUMO network has no DOCTYPE (external DTDs and entities are not read)",
                         file=name, line=line)
    counts = {"edges": 0, "internal_edges": 0, "lanes": 0, "junctions": 0, "traffic_lights": 0,
              "connections": 0, "roundabouts": 0}
    location = None
    root_seen = False
    lefthand = False
    # counted at the start of each element, let go at the end of each child of <net> with the ones before it:
    # a region's network (Columbus: 126 MB) is never a whole tree in memory (it was ~500 MB of the report stage)
    for event, element in iterparse_safe(source, events=("start", "end")):
        if event == "end":
            release_if_top_level(element)
            continue
        if not root_seen:
            root_seen = True
            if element.tag != "net":
                raise InputError(f"expected a SUMO network (<net>), found <{element.tag}>", file=name,
                                 line=element.sourceline)
            lefthand = element.get("lefthand", "false").lower() == "true"
            continue
        tag = element.tag
        if tag == "edge":
            counts["internal_edges" if element.get("function") == "internal" else "edges"] += 1
        elif tag == "lane":
            counts["lanes"] += 1
        elif tag == "junction" and element.get("type") != "internal":
            counts["junctions"] += 1
        elif tag == "tlLogic":
            counts["traffic_lights"] += 1
        elif tag == "connection":
            counts["connections"] += 1
        elif tag == "roundabout":
            counts["roundabouts"] += 1
        elif tag == "location" and location is None:
            location = _location(element, name)
    if counts["edges"] == 0:
        raise InputError("the SUMO network has no edges", file=name)
    centre = location.centre_wgs84() if location else None
    return {**counts, "location": location.to_dict() if location else None, "lefthand": lefthand,
            "centre_wgs84": list(centre) if centre else None}


def read_location(path: str | Path) -> Location:
    """The <location> element of a SUMO network (read from the start of the file only)."""
    from tavf_mapkit.xmlsafe import iterparse_safe, prepare_xml_bytes

    name = str(path)
    source = prepare_xml_bytes(read_net_bytes(path), name)
    for _event, element in iterparse_safe(source, events=("start",)):
        if element.tag == "location":
            return _location(element, name)
        if element.tag in ("edge", "junction"):
            break
    raise InputError("the SUMO network has no <location> element", file=name)


def plain_geo_centre(nodes_file: Path) -> tuple[float, float]:
    """(lon, lat) of the bbox centre of a plain-XML node file written with --proj.plain-geo."""
    from tavf_mapkit.xmlsafe import iterparse_safe, read_xml_source

    lons, lats = [], []
    for _event, element in iterparse_safe(read_xml_source(nodes_file), events=("end",)):
        if element.tag == "node" and element.get("x") is not None:
            lons.append(float(element.get("x")))
            lats.append(float(element.get("y")))
            element.clear()
    if not lons:
        raise InputError("the SUMO network has no nodes", file=str(nodes_file))
    return round((min(lons) + max(lons)) / 2, 7), round((min(lats) + max(lats)) / 2, 7)


def _location(element, name: str) -> Location:
    try:
        offset = tuple(float(v) for v in element.get("netOffset", "0,0").split(","))
        conv = tuple(float(v) for v in element.get("convBoundary", "0,0,0,0").split(","))
        orig = tuple(float(v) for v in element.get("origBoundary", "0,0,0,0").split(","))
    except ValueError:
        raise InputError("malformed <location> numbers", file=name, line=element.sourceline) from None
    if len(offset) != 2 or len(conv) != 4 or len(orig) != 4:
        raise InputError("malformed <location>", file=name, line=element.sourceline)
    return Location(offset, conv, orig, element.get("projParameter", "!"))
