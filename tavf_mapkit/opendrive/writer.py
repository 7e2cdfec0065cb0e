"""Model -> OpenDRIVE XML. Numbers are written with repr() so a load -> write -> load round trip is exact;
unknown elements and userData go back verbatim under the parent they came from.

Roads and junctions -- nearly all of a file, a region's millions of <geometry> records -- are written as text
(``_road_text``, ``_junction_text``), byte for byte what lxml makes of the same element tree (``_road``,
``_junction``) in a fifth of the time; an item with anything the text path does not know how to spell as lxml
does (a namespaced attribute or fragment, an attribute value that is not a string) is built as a tree.
"""

from __future__ import annotations

import hashlib
import re
from collections.abc import Iterator
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
from lxml import etree

from tavf_mapkit.fileutil import staged_file
from tavf_mapkit.opendrive.cubic import CubicProfile
from tavf_mapkit.opendrive.geometry import ELEMENT_NAMES, PARAMETER_NAMES, GeometryKind
from tavf_mapkit.opendrive.network import OpenDriveMap
from tavf_mapkit.opendrive.road import Road
from tavf_mapkit.opendrive.summary import COUNTED_NAMES, ElementCounts
from tavf_mapkit.xmlsafe import safe_parser


def _num(value: float) -> str:
    text = repr(float(value))
    return text.removesuffix(".0")


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


@dataclass(frozen=True)
class WrittenOpenDrive:
    """What ``write_opendrive`` knows of the file it wrote: its sha256 (hex, as ``manifest.file_sha256`` gives
    it) and its ``ElementCounts`` as a dict (what ``pipeline.summary.opendrive_counts`` of the file gives), None
    when a counted element in it has a @length that is no number (the pass over the file fails on it)."""

    sha256: str
    counts: dict | None


def write_opendrive(odr: OpenDriveMap, path: str | Path) -> WrittenOpenDrive:
    """Write atomically (a temporary file beside the target, then a rename), one top-level element at a time:
    a whole-document tree of a region's OpenDRIVE takes several GB (Maribor's build was killed at 6 GB).
    The file's sha256 and counts are taken as it is written: a region's is 500 MB, read again for each."""
    digest, counts = hashlib.sha256(), _WriterCounts()
    with staged_file(path) as temporary, open(temporary, "wb") as out:
        for piece in _serialized(odr, counts=counts):
            digest.update(piece)
            out.write(piece)
    return WrittenOpenDrive(digest.hexdigest(), None if counts.unreadable else counts.as_dict())


class _WriterCounts(ElementCounts):
    """``ElementCounts`` of the document as ``_serialized`` makes it: an item built as a tree is walked; a road
    or junction written as text is counted from the model it was written of (its own element, its signals and
    objects) and the verbatim fragments in it (``_Fragment`` lines). The text path writes no other element
    that is counted (``_model_name``). ``unreadable``: a counted road in a fragment has a @length that is no
    number (the writer writes it as it is: the counts are left to the pass over the file, which fails on it)."""

    __slots__ = ("unreadable",)

    def __init__(self) -> None:
        super().__init__()
        self.unreadable = False

    def add_tree(self, element) -> None:
        try:
            super().add_tree(element)
        except ValueError:
            self.unreadable = True

    def add_text(self, item, lines: list[str]) -> None:
        for line in lines:
            if type(line) is _Fragment:  # ended before the item that holds it
                self.add_tree(etree.fromstring(line.lstrip().encode("utf-8"), safe_parser()))
        if isinstance(item, Road):
            self.signals += len(item.signals)
            self.objects += len(item.objects)
            self.add_road(float(item.length))  # what float() of the written @length gives: repr round-trips
        else:  # a junction, a child of the document's root
            self.junctions += 1


def _serialized(odr: OpenDriveMap, as_text: bool = True, counts: _WriterCounts | None = None) -> Iterator[bytes]:
    """The document as pieces, each top-level element built, indented as in the whole tree and freed in turn.
    ``as_text=False`` builds every item as an lxml tree (what the text path must equal, byte for byte).
    ``counts``: what the document holds is counted into it as it is made."""
    yield b"<?xml version='1.0' encoding='UTF-8'?>\n<OpenDRIVE>\n"
    for item in _top_level(odr, as_text, counts):
        if isinstance(item, str):
            yield item.encode("utf-8")
            continue
        if counts is not None:
            counts.add_tree(item)
        for element in item:
            etree.indent(element, space="    ", level=1)
            yield b"    " + etree.tostring(element, encoding="UTF-8", with_tail=False) + b"\n"
    yield b"</OpenDRIVE>\n"


def _top_level(odr: OpenDriveMap, as_text: bool, counts: _WriterCounts | None = None
               ) -> Iterator[etree._Element | str]:
    """Per top-level item: its text (roads and junctions, see the module docstring), or a stand-in root holding
    that item's element(s) only."""
    def holder():
        return etree.Element("OpenDRIVE")

    root = holder()
    _header(root, odr.header)
    yield root
    for road in odr.roads:
        text = _text_or_none(_road_text, road, counts) if as_text else None
        if text is not None:
            yield text
            continue
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
        text = _text_or_none(_junction_text, junction, counts) if as_text else None
        if text is not None:
            yield text
            continue
        root = holder()
        _junction(root, junction)
        yield root
    root = holder()
    _append_verbatim(root, odr.extra_xml)
    yield root


def _junction(root, junction) -> None:
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


# -- the text path: the same elements as ``_road`` and ``_junction`` build, spelled as lxml serialises them ----

class _NotText(Exception):
    """Something the text path does not spell as lxml would: the item is built as a tree instead."""


def _text_or_none(make, item, counts: _WriterCounts | None = None) -> str | None:
    """``make(item)``'s lines joined (counted into ``counts``), or None when the item must be built as a tree."""
    try:
        lines = make(item)
    except _NotText:
        return None
    if counts is not None:
        counts.add_text(item, lines)
    return "\n".join(lines)


class _Fragment(str):
    """A line of text that is a verbatim fragment (``_verbatim_lines``): the writer's counts look into it."""

    __slots__ = ()


_PAD = tuple("    " * depth for depth in range(64))
_PLAIN_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_.-]*\Z")
# what lxml writes unchanged in an attribute value; anything else (markup, quotes, tabs, newlines, non-ASCII) is
# escaped by lxml itself (``_escaped``), so the two paths cannot differ
_PLAIN_VALUE = re.compile(r"[ !#-%'-;=?-~]*\Z")
_plain_names: set[str] = set()


def _name(key) -> str:
    if key in _plain_names:
        return key
    if not isinstance(key, str) or not _PLAIN_NAME.match(key):
        raise _NotText
    _plain_names.add(key)
    return key


def _model_name(key) -> str:
    """A tag the model holds (a lane record's, an outline corner's), as ``_name`` spells it; one the writer's
    counts look for (a "signal" record, were there one) is left to the tree path, whose counts see it."""
    if key in COUNTED_NAMES:
        raise _NotText
    return _name(key)


@lru_cache(maxsize=4096)
def _escaped(value: str) -> str:
    """An attribute value as lxml writes it (one tiny tree: values that need it are few and repeat)."""
    element = etree.Element("a")
    element.set("v", value)
    return etree.tostring(element, encoding="UTF-8").decode("utf-8")[6:-3]  # <a v="...."/>


def _quoted(value) -> str:
    if type(value) is not str:
        raise _NotText
    return value if _PLAIN_VALUE.match(value) else _escaped(value)


def _attributes(attrib: dict | None, values: dict) -> str:
    """`` name="value"`` of the attributes ``_sub`` gives an element: ``attrib`` in its order, ``values`` over it."""
    merged = dict(attrib) if attrib else {}
    for key, value in values.items():
        if value is None:
            merged.pop(key, None)
        else:
            merged[key] = _num(value) if isinstance(value, float) else str(value)
    return "".join([f' {_name(key)}="{_quoted(value)}"' for key, value in merged.items()])


def _element(out: list, depth: int, tag: str, attributes: str, children: list) -> None:
    """Append the lines of an element whose children's lines are ``children`` (a childless one closes itself)."""
    pad = _PAD[depth]
    if children:
        out.append(f"{pad}<{tag}{attributes}>")
        out += children
        out.append(f"{pad}</{tag}>")
    else:
        out.append(f"{pad}<{tag}{attributes}/>")


def _verbatim_lines(out: list, depth: int, fragments) -> None:
    """Unknown elements kept by the reader, indented as ``etree.indent`` of the whole item indents them."""
    for fragment in fragments or ():
        if b"xmlns" in fragment:  # namespace declarations: placed by lxml as the tree it is appended to says
            raise _NotText
        element = etree.fromstring(fragment, safe_parser())
        etree.indent(element, space="    ", level=depth)
        out.append(_Fragment(_PAD[depth] + etree.tostring(element, encoding="UTF-8", with_tail=False).decode("utf-8")))


def _cubic_lines(out: list, depth: int, tag: str, profile: CubicProfile, s_name: str = "s",
                 base: float = 0.0) -> None:
    pad, num = _PAD[depth], _num
    for s0, (a, b, c, d) in zip(profile.s0.tolist(), profile.coefficients.tolist()):
        out.append(f'{pad}<{tag} {s_name}="{num(s0 - base)}" a="{num(a)}" b="{num(b)}" c="{num(c)}" d="{num(d)}"/>')


_GEOMETRY_SPELLING = {int(kind): (ELEMENT_NAMES[kind], PARAMETER_NAMES[kind]) for kind in GeometryKind}
_LINE, _ARC = int(GeometryKind.LINE), int(GeometryKind.ARC)


def _spelled(values: np.ndarray) -> list[str]:
    """``_num`` of every value, in one pass over a list (a region's geometry records: tens of millions)."""
    return [text.removesuffix(".0") for text in map(repr, values.ravel().tolist())]


def _plan_view_lines(out: list, depth: int, reference_line) -> None:
    """The <geometry> records, from the reference line's rows (no Geometry objects: a region has millions)."""
    pad, inner, num = _PAD[depth], _PAD[depth + 1], _num
    rows = reference_line.narrow if not len(reference_line.side_index) else reference_line.rows
    extra_xml = reference_line.extra_xml or {}
    kinds = rows[:, 5].astype(np.int64)
    # s, x, y, hdg and length of every record spelled at once, and an arc's curvature: the only numbers a line
    # or an arc has (repr is most of the writer's time: not spent on the kind column or a line's unused slot)
    spelled = _spelled(rows[:, :5])
    curvatures = iter(_spelled(rows[kinds == _ARC, 6]))
    for k, kind in enumerate(kinds.tolist()):
        tag, names = _GEOMETRY_SPELLING[kind]
        s, x, y, hdg, length = spelled[5 * k:5 * k + 5]
        out.append(f'{pad}<geometry s="{s}" x="{x}" y="{y}" hdg="{hdg}" length="{length}">')
        if kind == _LINE:
            out.append(f"{inner}<line/>")
        elif kind == _ARC:
            out.append(f'{inner}<arc curvature="{next(curvatures)}"/>')
        else:
            params = rows[k, 6:6 + len(names)].tolist()
            shape = {}
            for name, value in zip(names, params):
                if name == "normalized":
                    shape["pRange"] = "normalized" if value > 0.5 else "arcLength"
                else:
                    shape[name] = num(value)
            if kind == int(GeometryKind.PARAM_POLY3) and len(params) < 9:
                shape["pRange"] = "normalized"
            out.append(f"{inner}<{tag}" + "".join([f' {key}="{value}"' for key, value in shape.items()]) + "/>")
        fragments = extra_xml.get(k)
        if fragments:
            _verbatim_lines(out, depth + 1, fragments)
        out.append(f"{pad}</geometry>")


def _link_lines(out: list, depth: int, tag: str, link) -> None:
    if link is not None:
        out.append(f"{_PAD[depth]}<{tag}" + _attributes(link.attrib, {
            "elementType": link.element_type, "elementId": link.element_id,
            "contactPoint": link.contact_point}) + "/>")


def _road_text(road) -> list[str]:
    """``_road``'s element as text: its lines at depth 1, as the document holds it (joined by newlines)."""
    out: list[str] = []
    extra = road.extra_xml
    children: list[str] = []
    if road.predecessor or road.successor or extra.get("link"):
        link: list[str] = []
        _link_lines(link, 3, "predecessor", road.predecessor)
        _link_lines(link, 3, "successor", road.successor)
        _verbatim_lines(link, 3, extra.get("link"))
        _element(children, 2, "link", "", link)
    for road_type in road.types:
        speed = [] if road_type.speed_attrib is None else \
            [f"{_PAD[3]}<speed" + _attributes(road_type.speed_attrib, {}) + "/>"]
        _element(children, 2, "type", _attributes(road_type.attrib, {"s": float(road_type.s0),
                                                                       "type": road_type.type}), speed)
    plan_view: list[str] = []
    _plan_view_lines(plan_view, 3, road.reference_line)
    _element(children, 2, "planView", "", plan_view)
    elevation: list[str] = []
    _cubic_lines(elevation, 3, "elevation", road.elevation)
    _verbatim_lines(elevation, 3, extra.get("elevationProfile"))
    _element(children, 2, "elevationProfile", "", elevation)
    lateral: list[str] = []
    _cubic_lines(lateral, 3, "superelevation", road.superelevation)
    for shape in road.shape:
        lateral.append(f"{_PAD[3]}<shape" + _attributes(None, {
            "s": float(shape.s0), "t": float(shape.t), **{k: float(v) for k, v in zip("abcd", shape.coefficients)}})
            + "/>")
    _verbatim_lines(lateral, 3, extra.get("lateralProfile"))
    _element(children, 2, "lateralProfile", "", lateral)
    lanes: list[str] = []
    _cubic_lines(lanes, 3, "laneOffset", road.lane_offset)
    for section in road.lane_sections:
        _lane_section_lines(lanes, 3, section)
    _verbatim_lines(lanes, 3, extra.get("lanes"))
    _element(children, 2, "lanes", "", lanes)
    if road.objects or extra.get("objects"):
        objects: list[str] = []
        for o in road.objects:
            _road_object_lines(objects, 3, o)
        _verbatim_lines(objects, 3, extra.get("objects"))
        _element(children, 2, "objects", "", objects)
    if road.signals or road.signal_references or extra.get("signals"):
        signals: list[str] = []
        for signal in road.signals:
            fragments: list[str] = []
            _verbatim_lines(fragments, 4, signal.extra_xml)
            _element(signals, 3, "signal", _attributes(signal.attrib, {
                "id": signal.id, "s": float(signal.s), "t": float(signal.t)}), fragments)
        for reference in road.signal_references:
            fragments = []
            _verbatim_lines(fragments, 4, reference.extra_xml)
            _element(signals, 3, "signalReference", _attributes(reference.attrib, {
                "id": reference.id, "s": float(reference.s), "t": float(reference.t)}), fragments)
        _verbatim_lines(signals, 3, extra.get("signals"))
        _element(children, 2, "signals", "", signals)
    _verbatim_lines(children, 2, extra.get("road"))
    _element(out, 1, "road", _attributes(road.attrib, {
        "id": road.id, "length": float(road.length), "junction": road.junction, "name": road.name}), children)
    out.append("")
    return out


def _lane_section_lines(out: list, depth: int, section) -> None:
    groups = (("left", sorted((lane for lane in section.lanes if lane.id > 0), key=lambda lane: -lane.id)),
              ("center", [lane for lane in section.lanes if lane.id == 0]),
              ("right", sorted((lane for lane in section.lanes if lane.id < 0), key=lambda lane: -lane.id)))
    children: list[str] = []
    for name, group in groups:
        if not group:
            continue
        lanes: list[str] = []
        for lane in group:
            _lane_lines(lanes, depth + 2, lane, section.s0)
        _element(children, depth + 1, name, "", lanes)
    _verbatim_lines(children, depth + 1, section.extra_xml)
    _element(out, depth, "laneSection", _attributes(section.attrib, {
        "s": float(section.s0), "singleSide": section.single_side}), children)


def _lane_lines(out: list, depth: int, lane, section_s0: float) -> None:
    inner, deeper = _PAD[depth + 1], _PAD[depth + 2]
    children: list[str] = []
    if lane.predecessor is not None or lane.successor is not None:
        link = []
        if lane.predecessor is not None:
            link.append(f"{deeper}<predecessor" + _attributes(None, {"id": lane.predecessor}) + "/>")
        if lane.successor is not None:
            link.append(f"{deeper}<successor" + _attributes(None, {"id": lane.successor}) + "/>")
        _element(children, depth + 1, "link", "", link)
    _cubic_lines(children, depth + 1, "width", lane.widths, "sOffset", section_s0)
    _cubic_lines(children, depth + 1, "border", lane.borders, "sOffset", section_s0)
    for mark in lane.road_marks:
        inside: list[str] = []
        if mark.lines or mark.type_name is not None:
            group_attributes = ""
            if not mark.explicit:
                if mark.type_name is not None:
                    group_attributes += f' name="{_quoted(mark.type_name)}"'
                if mark.type_width is not None:
                    group_attributes += f' width="{_num(mark.type_width)}"'
            lines = [f"{_PAD[depth + 3]}<line" + _attributes(line.attrib, {}) + "/>" for line in mark.lines]
            _element(inside, depth + 2, "explicit" if mark.explicit else "type", group_attributes, lines)
        _verbatim_lines(inside, depth + 2, mark.extra_xml)
        _element(children, depth + 1, "roadMark", _attributes(mark.attrib, {
            "sOffset": float(mark.s_offset - section_s0), "type": mark.type, "color": mark.color}), inside)
    for record in lane.records:
        fragments: list[str] = []
        _verbatim_lines(fragments, depth + 2, record.extra_xml)
        _element(children, depth + 1, _model_name(record.tag), _attributes(record.attrib, {
            "sOffset": float(record.s0 - section_s0)}), fragments)
    for height in lane.heights:
        children.append(f"{inner}<height" + _attributes(None, {
            "sOffset": float(height.s0 - section_s0), "inner": float(height.inner),
            "outer": float(height.outer)}) + "/>")
    _verbatim_lines(children, depth + 1, lane.extra_xml)
    _element(out, depth, "lane", _attributes(lane.attrib, {
        "id": lane.id, "type": lane.type, "level": "true" if lane.level else "false"}), children)


def _road_object_lines(out: list, depth: int, o) -> None:
    inner = _PAD[depth + 1]
    children = [f"{inner}<repeat" + _attributes(repeat.attrib, {}) + "/>" for repeat in o.repeats]
    for outline in o.outlines:
        corners = [f"{_PAD[depth + 2]}<{_model_name(corner.kind)}" + _attributes(corner.attrib, {}) + "/>"
                   for corner in outline.corners]
        _element(children, depth + 1, "outline", _attributes(outline.attrib, {}), corners)
    _verbatim_lines(children, depth + 1, o.extra_xml)
    _element(out, depth, "object", _attributes(o.attrib, {"id": o.id, "s": float(o.s), "t": float(o.t)}), children)


def _junction_text(junction) -> list[str]:
    """``_junction``'s element as text, at depth 1 (its lines, to be joined by newlines)."""
    children: list[str] = []
    for connection in junction.connections:
        inside = [f"{_PAD[3]}<laneLink" + _attributes(None, {"from": link.from_lane, "to": link.to_lane}) + "/>"
                  for link in connection.lane_links]
        _verbatim_lines(inside, 3, connection.extra_xml)
        _element(children, 2, "connection", _attributes(connection.attrib, {
            "id": connection.id, "incomingRoad": connection.incoming_road,
            "connectingRoad": connection.connecting_road, "contactPoint": connection.contact_point}), inside)
    for controller in junction.controllers:
        children.append(f"{_PAD[2]}<controller" + _attributes(None, {
            "id": controller.id, "type": controller.type, "sequence": controller.sequence}) + "/>")
    _verbatim_lines(children, 2, junction.extra_xml)
    out: list[str] = []
    _element(out, 1, "junction", _attributes(junction.attrib, {"id": junction.id}), children)
    out.append("")
    return out
