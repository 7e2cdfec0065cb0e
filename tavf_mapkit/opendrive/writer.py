"""Model -> OpenDRIVE XML. Numbers are written with repr() so a load -> write -> load round trip is exact;
unknown elements and userData go back verbatim under the parent they came from."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

from lxml import etree

from tavf_mapkit.opendrive.cubic import CubicProfile
from tavf_mapkit.opendrive.geometry import ELEMENT_NAMES, PARAMETER_NAMES, GeometryKind
from tavf_mapkit.opendrive.network import OpenDriveMap
from tavf_mapkit.fileutil import staged_file
from tavf_mapkit.xmlsafe import safe_parser


def _num(value: float) -> str:
    text = repr(float(value))
    return text[:-2] if text.endswith(".0") else text


def _sub(parent, tag: str, attrib: dict | None = None, **values) -> etree._Element:
    element = etree.SubElement(parent, tag)
    merged = dict(attrib or {})
    for key, value in values.items():
        if value is None:
            merged.pop(key, None)
        else:
            merged[key] = _num(value) if isinstance(value, float) else str(value)
    for key, value in merged.items():
        element.set(key, value)
    return element


def _append_verbatim(parent, fragments) -> None:
    for fragment in fragments or ():
        parent.append(etree.fromstring(fragment, safe_parser()))


def _cubic_records(parent, tag: str, profile: CubicProfile, s_name: str = "s", base: float = 0.0) -> None:
    for s0, (a, b, c, d) in zip(profile.s0, profile.coefficients):
        element = etree.SubElement(parent, tag)
        element.set(s_name, _num(s0 - base))
        for key, value in zip("abcd", (a, b, c, d)):
            element.set(key, _num(value))


def to_xml(odr: OpenDriveMap) -> bytes:
    return b"".join(_serialized(odr))


def write_opendrive(odr: OpenDriveMap, path: str | Path) -> None:
    """Write atomically (a temporary file beside the target, then a rename), one top-level element at a time:
    a whole-document tree of a region's OpenDRIVE takes several GB (Maribor's build was killed at 6 GB)."""
    with staged_file(path) as temporary, open(temporary, "wb") as out:
        for chunk in _serialized(odr):
            out.write(chunk)


def _serialized(odr: OpenDriveMap) -> Iterator[bytes]:
    """The document as pieces, each top-level element built, indented as in the whole tree and freed in turn."""
    yield b"<?xml version='1.0' encoding='UTF-8'?>\n<OpenDRIVE>\n"
    for holder in _top_level(odr):
        for element in holder:
            etree.indent(element, space="    ", level=1)
            yield b"    " + etree.tostring(element, encoding="UTF-8", with_tail=False) + b"\n"
    yield b"</OpenDRIVE>\n"


def _top_level(odr: OpenDriveMap) -> Iterator[etree._Element]:
    """A stand-in root per top-level item, holding that item's element(s) only."""
    def holder():
        return etree.Element("OpenDRIVE")

    root = holder()
    _header(root, odr.header)
    yield root
    for road in odr.roads:
        root = holder()
        _road(root, road)
        yield root
    for controller in odr.controllers:
        root = holder()
        element = _sub(root, "controller", controller.attrib, id=controller.id)
        for signal_id in controller.signal_ids:
            _sub(element, "control", signalId=signal_id)
        _append_verbatim(element, controller.extra_xml)
        yield root
    for junction in odr.junctions:
        root = holder()
        element = _sub(root, "junction", junction.attrib, id=junction.id)
        for connection in junction.connections:
            c = _sub(element, "connection", connection.attrib, id=connection.id,
                     incomingRoad=connection.incoming_road, connectingRoad=connection.connecting_road,
                     contactPoint=connection.contact_point)
            for link in connection.lane_links:
                _sub(c, "laneLink", **{"from": link.from_lane, "to": link.to_lane})
            _append_verbatim(c, connection.extra_xml)
        for controller in junction.controllers:
            _sub(element, "controller", id=controller.id, type=controller.type, sequence=controller.sequence)
        _append_verbatim(element, junction.extra_xml)
        yield root
    root = holder()
    _append_verbatim(root, odr.extra_xml)
    yield root


def _header(root, header) -> None:
    element = _sub(root, "header", header.attrib, revMajor=header.rev_major, revMinor=header.rev_minor,
                   name=header.name, version=header.version, date=header.date, north=float(header.north),
                   south=float(header.south), east=float(header.east), west=float(header.west), vendor=header.vendor)
    if header.geo_reference:
        geo = etree.SubElement(element, "geoReference")
        geo.text = etree.CDATA(header.geo_reference)
    if header.offset is not None:
        o = header.offset
        _sub(element, "offset", x=float(o.x), y=float(o.y), z=float(o.z), hdg=float(o.hdg))
    _append_verbatim(element, header.extra_xml)


def _link(parent, tag, link) -> None:
    if link is not None:
        _sub(parent, tag, link.attrib, elementType=link.element_type, elementId=link.element_id,
             contactPoint=link.contact_point)


def _road(root, road) -> None:
    element = _sub(root, "road", road.attrib, id=road.id, length=float(road.length), junction=road.junction,
                   name=road.name)
    extra = road.extra_xml
    if road.predecessor or road.successor or extra.get("link"):
        link = etree.SubElement(element, "link")
        _link(link, "predecessor", road.predecessor)
        _link(link, "successor", road.successor)
        _append_verbatim(link, extra.get("link"))
    for road_type in road.types:
        t = _sub(element, "type", road_type.attrib, s=float(road_type.s0), type=road_type.type)
        if road_type.speed_attrib is not None:
            _sub(t, "speed", road_type.speed_attrib)
    plan_view = etree.SubElement(element, "planView")
    for g in road.reference_line.geometries:
        geometry = _sub(plan_view, "geometry", s=float(g.s), x=float(g.x), y=float(g.y), hdg=float(g.hdg),
                        length=float(g.length))
        names = PARAMETER_NAMES[g.kind]
        shape = etree.SubElement(geometry, ELEMENT_NAMES[g.kind])
        for name, value in zip(names, g.params):
            if name == "normalized":
                shape.set("pRange", "normalized" if value > 0.5 else "arcLength")
            else:
                shape.set(name, _num(value))
        if g.kind is GeometryKind.PARAM_POLY3 and len(g.params) < 9:
            shape.set("pRange", "normalized")
        _append_verbatim(geometry, g.extra_xml)
    elevation = etree.SubElement(element, "elevationProfile")
    _cubic_records(elevation, "elevation", road.elevation)
    _append_verbatim(elevation, extra.get("elevationProfile"))
    lateral = etree.SubElement(element, "lateralProfile")
    _cubic_records(lateral, "superelevation", road.superelevation)
    for shape in road.shape:
        _sub(lateral, "shape", s=float(shape.s0), t=float(shape.t),
             **{k: float(v) for k, v in zip("abcd", shape.coefficients)})
    _append_verbatim(lateral, extra.get("lateralProfile"))
    lanes = etree.SubElement(element, "lanes")
    _cubic_records(lanes, "laneOffset", road.lane_offset)
    for section in road.lane_sections:
        _lane_section(lanes, section)
    _append_verbatim(lanes, extra.get("lanes"))
    if road.objects or extra.get("objects"):
        objects = etree.SubElement(element, "objects")
        for o in road.objects:
            _road_object(objects, o)
        _append_verbatim(objects, extra.get("objects"))
    if road.signals or road.signal_references or extra.get("signals"):
        signals = etree.SubElement(element, "signals")
        for signal in road.signals:
            e = _sub(signals, "signal", signal.attrib, id=signal.id, s=float(signal.s), t=float(signal.t))
            _append_verbatim(e, signal.extra_xml)
        for reference in road.signal_references:
            e = _sub(signals, "signalReference", reference.attrib, id=reference.id, s=float(reference.s),
                     t=float(reference.t))
            _append_verbatim(e, reference.extra_xml)
        _append_verbatim(signals, extra.get("signals"))
    _append_verbatim(element, extra.get("road"))


def _lane_section(lanes, section) -> None:
    element = _sub(lanes, "laneSection", section.attrib, s=float(section.s0), singleSide=section.single_side)
    groups = (("left", sorted((lane for lane in section.lanes if lane.id > 0), key=lambda lane: -lane.id)),
              ("center", [lane for lane in section.lanes if lane.id == 0]),
              ("right", sorted((lane for lane in section.lanes if lane.id < 0), key=lambda lane: -lane.id)))
    for name, group in groups:
        if not group:
            continue
        group_element = etree.SubElement(element, name)
        for lane in group:
            _lane(group_element, lane, section.s0)
    _append_verbatim(element, section.extra_xml)


def _lane(parent, lane, section_s0: float) -> None:
    element = _sub(parent, "lane", lane.attrib, id=lane.id, type=lane.type, level="true" if lane.level else "false")
    if lane.predecessor is not None or lane.successor is not None:
        link = etree.SubElement(element, "link")
        if lane.predecessor is not None:
            _sub(link, "predecessor", id=lane.predecessor)
        if lane.successor is not None:
            _sub(link, "successor", id=lane.successor)
    _cubic_records(element, "width", lane.widths, "sOffset", section_s0)
    _cubic_records(element, "border", lane.borders, "sOffset", section_s0)
    for mark in lane.road_marks:
        m = _sub(element, "roadMark", mark.attrib, sOffset=float(mark.s_offset - section_s0), type=mark.type,
                 color=mark.color)
        if mark.lines or mark.type_name is not None:
            group = etree.SubElement(m, "explicit" if mark.explicit else "type")
            if not mark.explicit:
                if mark.type_name is not None:
                    group.set("name", mark.type_name)
                if mark.type_width is not None:
                    group.set("width", _num(mark.type_width))
            for line in mark.lines:
                _sub(group, "line", line.attrib)
        _append_verbatim(m, mark.extra_xml)
    for record in lane.records:
        r = _sub(element, record.tag, record.attrib, sOffset=float(record.s0 - section_s0))
        _append_verbatim(r, record.extra_xml)
    for height in lane.heights:
        _sub(element, "height", sOffset=float(height.s0 - section_s0), inner=float(height.inner),
             outer=float(height.outer))
    _append_verbatim(element, lane.extra_xml)


def _road_object(parent, o) -> None:
    element = _sub(parent, "object", o.attrib, id=o.id, s=float(o.s), t=float(o.t))
    for repeat in o.repeats:
        _sub(element, "repeat", repeat.attrib)
    for outline in o.outlines:
        outline_element = _sub(element, "outline", outline.attrib)
        for corner in outline.corners:
            _sub(outline_element, corner.kind, corner.attrib)
    _append_verbatim(element, o.extra_xml)
