"""OpenDRIVE 1.4-1.8 reader: safe, streaming (one top-level element at a time), never a traceback.

Unknown elements and userData are kept verbatim so the writer can put them back. Numbers are checked:
NaN, infinity and negative lengths are reported with file, line and road id.
"""

from __future__ import annotations

from itertools import pairwise
from pathlib import Path

import numpy as np
from lxml import etree

from tavf_mapkit.errors import InputError
from tavf_mapkit.memory import collector_paused
from tavf_mapkit.opendrive.cubic import ProfileInterner
from tavf_mapkit.opendrive.diagnostics import Diagnostic
from tavf_mapkit.opendrive.geometry import NARROW_COLUMNS, GeometryKind, join_rows
from tavf_mapkit.opendrive.header import Header, Offset
from tavf_mapkit.opendrive.junction import Connection, Controller, Junction, JunctionController, LaneLink
from tavf_mapkit.opendrive.lane import Lane, LaneHeight, LaneRecord, RoadMark, RoadMarkLine
from tavf_mapkit.opendrive.lanes_scan import BIG_LINE, LANES_CLOSE, LANES_OPEN, LanesLayout, lane_line
from tavf_mapkit.opendrive.lanesection import LaneSection
from tavf_mapkit.opendrive.network import OpenDriveMap
from tavf_mapkit.opendrive.objects import (
    ObjectRepeat,
    Outline,
    OutlineCorner,
    RoadObject,
    Signal,
    SignalReference,
)
from tavf_mapkit.opendrive.planview_scan import PlanViewMismatch, PlanViewScan
from tavf_mapkit.opendrive.refline import ReferenceLine, RowPacker
from tavf_mapkit.opendrive.road import Road, RoadLink, RoadType, ShapeRecord
from tavf_mapkit.opendrive.units import speed_to_mps
from tavf_mapkit.xmlsafe import XmlSource, iterparse_safe, prepare_xml_bytes, read_xml_source, safe_parser

_GEOMETRY_TAGS = {
    "line": GeometryKind.LINE, "arc": GeometryKind.ARC, "spiral": GeometryKind.SPIRAL,
    "poly3": GeometryKind.POLY3, "paramPoly3": GeometryKind.PARAM_POLY3,
}
_GEOMETRY_TAG_SET = set(_GEOMETRY_TAGS)
_CUBIC = ("a", "b", "c", "d")
_CUBIC_KEYS = list(_CUBIC)
_LANE_RECORDS = frozenset({"speed", "access", "material", "visibility", "rule"})
_LANE_GROUPS = ("left", "center", "right")
_LANES_CONTENTS_KEPT = 1 << 15  # lanes contents whose profiles are kept (bounded memory: the rest are made again)
_SHARED_NUMBER_LENGTH = 6  # attribute values this short are shared even when they are numbers (Reader.attrib)


def load_opendrive(path: str | Path) -> OpenDriveMap:
    """Read an OpenDRIVE file; raises InputError (one line, with location) if it cannot be read."""
    return _read(read_xml_source(path))


def loads_opendrive(data: bytes | str, name: str = "<string>") -> OpenDriveMap:
    if isinstance(data, str):
        data = data.encode("utf-8")
    return _read(prepare_xml_bytes(data, name))


def _read(source: XmlSource) -> OpenDriveMap:
    with collector_paused():
        try:
            return _Reader(source, scan_plan_views=True).read()
        except PlanViewMismatch:  # a planView the scan emptied was not a road's (planview_scan.py): read it all
            return _Reader(source).read()


_PARAM_POLY3_NAMES = ("aU", "bU", "cU", "dU", "aV", "bV", "cV", "dV")


def _plain_geometry_row(g) -> tuple | None:
    """(narrow row, 9 parameters or None) of a <geometry> in its common, flawless form -- one <line>, <arc> or
    <paramPoly3> child, every number present and finite, a positive length -- or None, and the careful path (with
    its warnings and one-line errors) reads it instead. Curves as arcs give city maps millions of these, so this
    is the hot path: a geometry with exactly netconvert's attributes is read in one call (``values``)."""
    if len(g) != 1:
        return None
    shape = g[0]
    tag = shape.tag
    try:
        if g.keys() == _GEOMETRY_KEYS:
            s, x, y, hdg, length = map(float, g.values())
        else:
            attrib = g.attrib
            s, x, y, length = float(attrib["s"]), float(attrib["x"]), float(attrib["y"]), float(attrib["length"])
            hdg = float(attrib.get("hdg", 0.0))
        if tag == "arc":
            side = None
            if shape.keys() == _CURVATURE_KEYS:
                row = (s, x, y, hdg, length, _ARC, float(shape.values()[0]))
            else:
                row = (s, x, y, hdg, length, _ARC, float(shape.attrib["curvature"]))
            total = s + x + y + hdg + length + row[6]
        elif tag == "line":
            side = None
            row = (s, x, y, hdg, length, _LINE, 0.0)
            total = s + x + y + hdg + length
        elif tag == "paramPoly3":
            p_range = shape.get("pRange", "normalized")
            if p_range not in ("normalized", "arcLength"):
                return None
            shape_attrib = shape.attrib
            side = tuple(float(shape_attrib.get(name, 0.0)) for name in _PARAM_POLY3_NAMES) + (
                1.0 if p_range == "normalized" else 0.0,)
            row = (s, x, y, hdg, length, _PARAM_POLY3, side[0])
            total = s + x + y + hdg + length + sum(side)
        else:
            return None
    except (KeyError, ValueError):
        return None
    if total - total != 0.0 or not length > 0.0:  # NaN or infinity somewhere, or a length to warn about
        return None
    return row, side


_GEOMETRY_KEYS = ["s", "x", "y", "hdg", "length"]
_CURVATURE_KEYS = ["curvature"]
_LINE, _ARC, _PARAM_POLY3 = int(GeometryKind.LINE), int(GeometryKind.ARC), int(GeometryKind.PARAM_POLY3)


def _local(tag) -> str:
    if not isinstance(tag, str):
        return ""
    return tag.rsplit("}", 1)[-1]


def _strip_namespace(element) -> None:
    """OpenDRIVE has no namespace, but some writers add one; plain tags keep the converters simple and fast."""
    if element.tag[0] != "{":
        return
    for node in element.iter():
        if isinstance(node.tag, str) and node.tag[0] == "{":
            node.tag = node.tag.rsplit("}", 1)[-1]


def _verbatim(element) -> bytes:
    text = etree.tostring(element, with_tail=False)
    return text


class _Reader:
    def __init__(self, source: XmlSource, scan_plan_views: bool = False):
        self.source = source
        self.scan = None  # the PlanViewScan the parser reads through, if any
        self.scan_plan_views = scan_plan_views
        self.warnings: list[Diagnostic] = []
        self.road_id: str | None = None
        self.strings: dict[str, str] = {}
        self.packer = RowPacker()  # the reference lines' rows in shared arrays, not one small array per road
        self.attribs: dict[tuple, dict] = {}  # shared_attrib
        self.raw_attribs: dict[tuple, dict] = {}  # shared_attrib by the element's own (name, value) pairs
        self.profiles = ProfileInterner()  # identical cubic profiles shared (lane widths, flat elevations)
        self.marks: dict[tuple, RoadMark] = {}  # identical plain road marks shared (road_mark)
        self.records: dict[tuple, LaneRecord] = {}  # identical plain lane records shared (lane_record)
        self.tuples: dict[tuple, tuple] = {}  # shared_tuple
        self.lane_recipes: dict[bytes, tuple] = {}  # recipe_lanes, by template
        self.lane_profiles: dict[bytes, tuple] = {}  # recipe_profiles, by content (at most _LANES_CONTENTS_KEPT)

    # -- helpers ---------------------------------------------------------------------------------------------
    def word(self, element, name: str, default: str | None = None) -> str | None:
        """An attribute whose values repeat across the map (a type, a rule, a road id), shared (see attrib)."""
        value = element.get(name)
        return default if value is None else self.strings.setdefault(value, value)

    def attrib(self, element) -> dict:
        """The element's attributes as a dict, names and word values shared: a city map has millions of
        attributes, mostly the same few names and words ("type", "driving", "solid"), and lxml makes a new
        string for each. Long numbers are not shared (nearly all distinct); short ones are (a lane's id "-1", a
        mark's width "0.13", a speed "13.89", an sOffset "0": the same few on every lane of a city)."""
        strings = self.strings
        out = {}
        for name, value in element.attrib.items():
            name = strings.setdefault(name, name)
            if value and (len(value) <= _SHARED_NUMBER_LENGTH or not (value[0].isdigit() or value[0] in "-+.")):
                value = strings.setdefault(value, value)
            out[name] = value
        return out

    def shared_attrib(self, element) -> dict:
        """``attrib``, one dict for every element with the same attributes (a city's lanes, road marks and lane
        records repeat a few: {id: -1, type: driving, level: true}). The model's attribute dicts are never
        changed in place (a repair copies one to change it), so sharing them is safe."""
        raw = tuple(element.items())
        out = self.raw_attribs.get(raw)
        if out is None:
            out = self.attrib(element)
            out = self.raw_attribs[raw] = self.attribs.setdefault(tuple(out.items()), out)
        return out

    def line(self, element) -> int | None:
        line = element.sourceline  # computed by lxml on each read
        return line + self.source.line_offset if line else None

    def error(self, message: str, element=None, road: str | None = None) -> InputError:
        return InputError(message, file=self.source.name, line=self.line(element) if element is not None else None,
                          element=_local(element.tag) if element is not None else None,
                          road=road if road is not None else self.road_id)

    def warn(self, message: str, element=None) -> None:
        self.warnings.append(Diagnostic(message, self.line(element) if element is not None else None,
                                        self.road_id, _local(element.tag) if element is not None else None))

    def number(self, element, name: str, default: float | None = None, required: bool = False,
               minimum: float | None = None) -> float | None:
        raw = element.get(name)
        if raw is None:
            if required:
                raise self.error(f"missing required attribute @{name}", element)
            return default
        try:
            value = float(raw)
        except ValueError:
            if not raw.strip():
                if required:
                    raise self.error(f"missing required attribute @{name}", element) from None
                return default
            raise self.error(f"@{name}={raw!r} is not a number", element) from None
        if value - value != 0.0:  # NaN or infinity, without a function call on the hot path
            raise self.error(f"@{name}={raw!r} is not a finite number", element)
        if minimum is not None and value < minimum:
            raise self.error(f"@{name}={raw} must be >= {minimum:g}", element)
        return value

    def integer(self, element, name: str, default: int | None = None, required: bool = False) -> int | None:
        value = self.number(element, name, None, required)
        if value is None:
            return default
        if value != int(value):
            raise self.error(f"@{name}={element.get(name)!r} is not an integer", element)
        return int(value)

    def cubic(self, element, s_name: str = "s", base: float = 0.0) -> tuple[float, ...]:
        keys = element.keys()
        if len(keys) == 5 and keys[0] == s_name and keys[1:] == _CUBIC_KEYS:  # as netconvert writes them
            try:
                s, a, b, c, d = map(float, element.values())
            except ValueError:
                pass  # the careful path names the attribute
            else:
                total = s + a + b + c + d
                if total - total == 0.0:  # all finite
                    return base + s, a, b, c, d
        number = self.number
        return (base + number(element, s_name, 0.0), number(element, "a", 0.0), number(element, "b", 0.0),
                number(element, "c", 0.0), number(element, "d", 0.0))

    @staticmethod
    def children(element, tag: str):
        return list(element.iterchildren(tag))  # findall's path machinery costs ~10x on a map's many small lists

    @staticmethod
    def child(element, tag: str):
        return next(element.iterchildren(tag), None)

    @staticmethod
    def unknown(element, known: set[str]) -> tuple[bytes, ...]:
        if not len(element):
            return ()
        return tuple(_verbatim(child) for child in element if child.tag not in known and isinstance(child.tag, str))

    # -- document ------------------------------------------------------------------------------------------
    def read(self) -> OpenDriveMap:
        header = None
        roads, junctions, controllers, extras = [], [], [], []
        handlers = {"header": None, "road": roads, "junction": junctions, "controller": controllers}
        root = None
        # only top-level elements are converted, then cleared: memory stays bounded on huge files
        scan = None
        if self.scan_plan_views:
            def scan(stream):
                self.scan = PlanViewScan(stream, self.source.line_offset)
                return self.scan
        for _, element in iterparse_safe(self.source, events=("end",),
                                         tag=("{*}header", "{*}road", "{*}junction", "{*}controller"),
                                         stream_filter=scan):
            parent = element.getparent()
            if parent is None or parent.getparent() is not None:
                continue  # e.g. <controller> inside <junction>
            if root is None:
                root = parent
                self.check_root(root)
            _strip_namespace(element)
            tag = element.tag
            if tag == "header":
                header = self.header(element)
            elif tag == "road":
                roads.append(self.road(element))
            elif tag == "junction":
                junctions.append(self.junction(element))
            else:
                controllers.append(self.controller(element))
            element.clear()
            while element.getprevious() is not None:
                previous = parent[0]
                if isinstance(previous.tag, str) and _local(previous.tag) not in handlers:
                    extras.append(_verbatim(previous))
                del parent[0]
        self.packer.flush()
        if self.scan is not None and (self.scan.blocks or self.scan.lanes_blocks):
            raise PlanViewMismatch  # an emptied planView or lanes no road read
        root = root if root is not None else self.source.root
        if root is None:
            raise InputError("empty document, expected <OpenDRIVE>", file=self.source.name)
        self.check_root(root)
        for element in root:
            if isinstance(element.tag, str) and _local(element.tag) not in handlers:
                extras.append(_verbatim(element))
        if header is None:
            self.warnings.append(Diagnostic("no <header>; assuming OpenDRIVE 1.4 without georeference"))
            header = Header()
        self.check_links(roads, junctions)
        return OpenDriveMap(header, tuple(roads), tuple(junctions), tuple(controllers), self.source.name,
                            tuple(self.warnings), tuple(extras))

    def check_root(self, root) -> None:
        if _local(root.tag) != "OpenDRIVE":
            raise self.error(f"root element is <{_local(root.tag)}>, expected <OpenDRIVE>", root)

    def header(self, element) -> Header:
        self.road_id = None
        geo = self.child(element, "geoReference")
        offset_element = self.child(element, "offset")
        offset = None
        if offset_element is not None:
            offset = Offset(*(self.number(offset_element, k, 0.0) for k in ("x", "y", "z", "hdg")))
        geo_text = None
        if geo is not None:
            geo_text = "".join(geo.itertext()).strip() or None
            if geo_text is None:  # e.g. CommonRoad's converter writes a placeholder <TODO/>
                inside = ", ".join(f"<{_local(child.tag)}/>" for child in geo if isinstance(child.tag, str))
                self.warn("geoReference holds no PROJ string" + (f" (only {inside})" if inside else "")
                          + ": the map is not georeferenced", geo)
        known = {"geoReference", "offset"}
        return Header(
            rev_major=self.integer(element, "revMajor", 1), rev_minor=self.integer(element, "revMinor", 4),
            name=element.get("name", ""), version=element.get("version"), date=element.get("date"),
            north=self.number(element, "north", 0.0), south=self.number(element, "south", 0.0),
            east=self.number(element, "east", 0.0), west=self.number(element, "west", 0.0),
            vendor=element.get("vendor"), geo_reference=geo_text, offset=offset, line=self.line(element),
            attrib=self.attrib(element), extra_xml=self.unknown(element, known),
        )

    # -- roads -----------------------------------------------------------------------------------------------
    def road(self, element) -> Road:
        road_id = element.get("id")
        self.road_id = road_id
        if road_id is None:
            raise self.error("road without @id", element, road="?")
        length = self.number(element, "length", required=True)
        if length < 0:
            raise self.error(f"@length={element.get('length')} is negative", element)
        # one pass over the road's children, not a search per kind of child (roads are many, children few)
        first, types_elements = {}, []
        for child in element:
            tag = child.tag
            if tag == "type":
                types_elements.append(child)
            elif tag not in first:
                first[tag] = child
        child = first.get
        link = child("link")
        predecessor = successor = None
        extra = {}
        if link is not None:
            predecessor = self.road_link(self.child(link, "predecessor"))
            successor = self.road_link(self.child(link, "successor"))
            extra["link"] = self.unknown(link, {"predecessor", "successor"})
        types = tuple(self.road_type(t) for t in types_elements)
        plan_view = child("planView")
        reference_line = self.plan_view(plan_view) if plan_view is not None else ReferenceLine()
        self.packer.add(reference_line)
        if plan_view is None:
            self.warn("road has no <planView>", element)
        elevation = superelevation = lane_offset = None
        shape = ()
        profile = child("elevationProfile")
        if profile is not None:
            elevation = self.profiles.profile([self.cubic(e) for e in self.children(profile, "elevation")])
            extra["elevationProfile"] = self.unknown(profile, {"elevation"})
        lateral = child("lateralProfile")
        if lateral is not None:
            superelevation = self.profiles.profile(
                [self.cubic(e) for e in self.children(lateral, "superelevation")])
            shape = tuple(ShapeRecord(self.number(e, "s", 0.0), self.number(e, "t", 0.0),
                                      tuple(self.number(e, k, 0.0) for k in _CUBIC))
                          for e in self.children(lateral, "shape"))
            extra["lateralProfile"] = self.unknown(lateral, {"superelevation", "shape"})
        lanes = child("lanes")
        sections: tuple[LaneSection, ...] = ()
        if lanes is not None:
            taken = self.scan.take_lanes(lanes.sourceline, lanes.text) if self.scan and not len(lanes) else None
            if taken is not None:  # emptied by the scan: made from the content's recipe (lanes_scan.py)
                lane_offset, sections = self.recipe_lanes(*taken)
            else:
                lane_offset, sections = self.lanes(lanes)
                extra["lanes"] = self.unknown(lanes, {"laneOffset", "laneSection"})
            self.warn_zero_length(sections)
        if not sections:
            self.warn("road has no lane section", element)
        objects_element = child("objects")
        objects = ()
        if objects_element is not None:
            objects = tuple(self.road_object(o) for o in self.children(objects_element, "object"))
            extra["objects"] = self.unknown(objects_element, {"object"})
        signals_element = child("signals")
        signals, references = (), ()
        if signals_element is not None:
            signals = tuple(self.signal(s) for s in self.children(signals_element, "signal"))
            references = tuple(self.signal_reference(s) for s in self.children(signals_element, "signalReference"))
            extra["signals"] = self.unknown(signals_element, {"signal", "signalReference"})
        extra["road"] = self.unknown(element, {"link", "type", "planView", "elevationProfile", "lateralProfile",
                                               "lanes", "objects", "signals"})
        kwargs = {}
        if elevation is not None:
            kwargs["elevation"] = elevation
        if superelevation is not None:
            kwargs["superelevation"] = superelevation
        if lane_offset is not None:
            kwargs["lane_offset"] = lane_offset
        return Road(
            id=road_id, length=length, reference_line=reference_line, lane_sections=sections,
            junction=self.word(element, "junction", "-1"), name=element.get("name", ""), rule=self.word(element, "rule", "RHT"),
            predecessor=predecessor, successor=successor, types=types, shape=shape, objects=objects,
            signals=signals, signal_references=references, line=self.line(element), attrib=self.attrib(element),
            extra_xml={k: v for k, v in extra.items() if v}, **kwargs,
        )

    def road_link(self, element) -> RoadLink | None:
        if element is None:
            return None
        element_id = self.word(element, "elementId")
        if element_id is None:
            raise self.error("link without @elementId", element)
        return RoadLink(self.word(element, "elementType", "road"), element_id, self.word(element, "contactPoint"),
                        self.shared_attrib(element))

    def road_type(self, element) -> RoadType:
        speed = self.child(element, "speed")
        speed_max = None
        if speed is not None:
            speed_max = speed_to_mps(speed.get("max"), speed.get("unit"))
        return RoadType(self.number(element, "s", 0.0), element.get("type", "unknown"), element.get("country"),
                        speed_max, self.shared_attrib(element),
                        self.shared_attrib(speed) if speed is not None else None)

    def plan_view(self, element) -> ReferenceLine:
        if self.scan is not None and not len(element):
            scanned = self.scan.take(element.sourceline, element.text)
            if scanned is not None:  # read before the parser saw it (planview_scan.py)
                narrow, lines, in_order = scanned
                if in_order:
                    return ReferenceLine.from_narrow(narrow, None, None, lines)
                return self.reference_line(narrow, lines, [], [], {})
        # narrow rows, not Geometry objects: a map's curves as arcs are millions of records (see refline.py)
        # rows: the narrow rows' values one after another (one array made of them at the end); lines: one per row
        rows, lines, side_index, side_params, extra_xml = [], [], [], [], {}
        line_offset = self.source.line_offset
        for g in element.iterchildren("geometry"):
            if g.keys() == _GEOMETRY_KEYS and len(g) == 1:
                # the hot path, inline: a line or an arc with netconvert's attributes, every number finite
                shape = g[0]
                tag = shape.tag
                try:
                    s, x, y, hdg, length = map(float, g.values())
                    if tag == "arc" and shape.keys() == _CURVATURE_KEYS:
                        curvature = float(shape.values()[0])
                    elif tag == "line" and not shape.keys():
                        curvature = 0.0
                    else:
                        curvature = None
                except ValueError:
                    curvature = None
                if curvature is not None:
                    total = s + x + y + hdg + length + curvature
                    if total - total == 0.0 and length > 0.0:
                        rows += (s, x, y, hdg, length, _ARC if tag == "arc" else _LINE, curvature)
                        line = g.sourceline  # a property lxml computes: read once
                        lines.append(line + line_offset if line else -1)
                        continue
            plain = _plain_geometry_row(g)
            if plain is not None:
                row, params = plain
                if params is not None:
                    side_index.append(len(lines))
                    side_params.append(params)
                rows += row
                line = g.sourceline
                lines.append(line + line_offset if line else -1)
                continue
            s = self.number(g, "s", required=True)
            x = self.number(g, "x", required=True)
            y = self.number(g, "y", required=True)
            hdg = self.number(g, "hdg", 0.0)
            length = self.number(g, "length", required=True)
            if length < 0:
                self.warn(f"geometry at s={s:g} has negative @length={length:g}; skipped", g)
                continue
            kind_element = next((c for c in g if isinstance(c.tag, str)), None)
            if kind_element is None:
                self.warn(f"geometry at s={s:g} has no shape element; skipped", g)
                continue
            tag = _local(kind_element.tag)
            kind = _GEOMETRY_TAGS.get(tag)
            if kind is None:
                self.warn(f"unknown geometry element <{tag}> at s={s:g}; skipped", kind_element)
                continue
            if kind is GeometryKind.ARC:
                params = (self.number(kind_element, "curvature", required=True),)
            elif kind is GeometryKind.SPIRAL:
                params = (self.number(kind_element, "curvStart", required=True),
                          self.number(kind_element, "curvEnd", required=True))
            elif kind is GeometryKind.POLY3:
                params = tuple(self.number(kind_element, k, 0.0) for k in _CUBIC)
            elif kind is GeometryKind.PARAM_POLY3:
                p_range = kind_element.get("pRange", "normalized")
                if p_range not in ("normalized", "arcLength"):
                    raise self.error(f"@pRange={p_range!r} must be 'arcLength' or 'normalized'", kind_element)
                params = tuple(self.number(kind_element, k, 0.0)
                               for k in ("aU", "bU", "cU", "dU", "aV", "bV", "cV", "dV"))
                params += (1.0 if p_range == "normalized" else 0.0,)
            else:
                params = ()
            if length == 0.0:
                self.warn(f"zero-length <{tag}> geometry at s={s:g}; tolerated", g)
            unknown = self.unknown(g, _GEOMETRY_TAG_SET)
            if unknown:
                extra_xml[len(lines)] = unknown
            if kind >= GeometryKind.SPIRAL:  # more parameters than the narrow row holds (geometry.NARROW_COLUMNS)
                side_index.append(len(lines))
                side_params.append(params + (0.0,) * (9 - len(params)))
            rows += (s, x, y, hdg, length, int(kind), params[0] if params else 0.0)
            line = self.line(g)
            lines.append(-1 if line is None else line)
        narrow = np.fromiter(rows, dtype=float, count=len(rows)).reshape(-1, NARROW_COLUMNS)
        return self.reference_line(narrow, np.array(lines, dtype=np.int32), side_index, side_params, extra_xml)

    @staticmethod
    def reference_line(narrow, lines, side_index: list, side_params: list, extra_xml: dict) -> ReferenceLine:
        if len(narrow) > 1 and np.any(narrow[1:, 0] < narrow[:-1, 0]):
            # out of order in the file: sorted by s, stable like the records' own order (a rare, careful path)
            wide = join_rows(narrow, np.array(side_index, dtype=np.int64), np.array(side_params).reshape(-1, 9))
            order = np.argsort(narrow[:, 0], kind="stable")
            extra_xml = {int(np.flatnonzero(order == k)[0]): v for k, v in extra_xml.items()}
            return ReferenceLine.from_rows(wide[order], lines[order], extra_xml)
        if not side_index:
            return ReferenceLine.from_narrow(narrow, None, None, lines, extra_xml)
        return ReferenceLine.from_narrow(narrow, np.array(side_index, dtype=np.int64),
                                         np.array(side_params, dtype=float).reshape(-1, 9), lines, extra_xml)

    def lanes(self, element) -> tuple:
        """(lane offset profile, lane sections) of a <lanes>."""
        return (self.profiles.profile([self.cubic(e) for e in self.children(element, "laneOffset")]),
                self.lane_sections(element))

    def recipe_lanes(self, content: bytes, template: tuple, layout: LanesLayout, tag_line: int) -> tuple:
        """``lanes`` of an emptied <lanes> (lanes_scan.py): from its template's recipe, read once per template,
        with this road's numbers and source lines. Its objects are those ``lanes`` makes: the lane sections,
        the lanes and their tuples anew, the rest shared as ``lanes`` shares it (profiles, marks, records,
        attributes, words)."""
        key, values = template
        recipe = self.lane_recipes.get(key)
        if recipe is None:
            recipe = self.lane_recipes[key] = self.lanes_recipe(content, layout)
        section_recipes = recipe[1]
        profiles = self.lane_profiles.get(content)  # most contents repeat whole: their profiles too
        if profiles is None:
            profiles = self.recipe_profiles(recipe, values)
            if len(self.lane_profiles) < _LANES_CONTENTS_KEPT:
                self.lane_profiles[content] = profiles
        lane_offset, lane_profiles = profiles
        lane_profiles = iter(lane_profiles)
        line = tag_line + self.source.line_offset
        big = tag_line + layout.newlines >= BIG_LINE  # past libxml2's 16-bit lines (lanes_scan.LanesLayout)
        return lane_offset, tuple([
            LaneSection(s0, tuple([
                Lane(*head, *next(lane_profiles), *tail, lane_line(line, tag_line, lines) if big else line + lines[0],
                     attrib)
                for head, tail, lines, attrib in lanes]),
                None, lane_line(line, tag_line, section_lines) if big else line + section_lines[0], section_attrib)
            for s0, section_lines, section_attrib, lanes, _ in section_recipes])

    def recipe_profiles(self, recipe: tuple, values: list[bytes]) -> tuple:
        """(lane offset, ((widths, borders) of each lane of each section, in order)) of a lanes recipe with these
        numbers, as ``lanes`` makes them (cubic, then the shared profile)."""
        try:
            numbers = list(map(float, values))
        except ValueError:  # e.g. "1e5e5" or "": the careful path names it or reads it as 0
            raise PlanViewMismatch from None
        total = sum(numbers)
        if total - total != 0.0:  # NaN or infinity: the careful path's error names it
            raise PlanViewMismatch
        records = list(zip(*[iter(numbers)] * 5))  # (s, a, b, c, d) of each cubic record
        profile = self.profiles.profile
        offset_holes, section_recipes = recipe
        return profile([(0.0 + s, a, b, c, d) for s, a, b, c, d in map(records.__getitem__, offset_holes)]), [
            (profile([(s0 + s, a, b, c, d) for s, a, b, c, d in map(records.__getitem__, widths)], True),
             profile([(s0 + s, a, b, c, d) for s, a, b, c, d in map(records.__getitem__, borders)], True))
            for s0, _, _, _, cubic_records in section_recipes for widths, borders in cubic_records]

    def lanes_recipe(self, content: bytes, layout: LanesLayout) -> tuple:
        """(the lane offset's cubic records, (s0, lines, attributes, lanes, cubic records) per section) of a
        plain lanes content, a lane as (id .. successor, heights .. records, lines, attributes), its cubic
        records as (its widths', its borders'); a cubic record as its index among the template's
        (lanes_scan.lanes_template), lines as its start tag's (LanesLayout.tag_lines, next_tag_lines). Read by ``lanes`` from the content as a fragment
        with the start tags' indices in place of lines. Raises PlanViewMismatch where the content would not make such
        objects (an error, a string or bytes the careful path makes for each road): the careful path reads the
        file."""
        try:
            root = etree.fromstring(LANES_OPEN + content + LANES_CLOSE, safe_parser())
        except etree.XMLSyntaxError:
            raise PlanViewMismatch from None
        elements = list(root.iter())[1:]  # the plain form has no comment or PI: elements in start tag order
        if len(elements) != len(layout.tag_lines):
            raise PlanViewMismatch
        self.line = {element: index for index, element in enumerate(elements)}.__getitem__
        try:
            _, sections = self.lanes(root)
            unknown = self.unknown(root, {"laneOffset", "laneSection"})
        except InputError:
            raise PlanViewMismatch from None
        finally:
            del self.line  # the method again
        # the template's holes are the cubic records in the order of the file, five numbers each
        cubic_record = {element: k for k, element in enumerate(
            e for e in elements if e.tag in ("laneOffset", "width", "border"))}

        def tag_lines(index: int) -> tuple[int, int]:
            return layout.tag_lines[index], layout.next_tag_lines[index]
        recipes = []
        for section in sections:
            if section.single_side is not None or section.extra_xml or unknown:
                raise PlanViewMismatch  # a string or bytes the careful path makes for each road
            lanes, cubic_records = [], []
            for lane in section.lanes:
                if lane.heights or lane.extra_xml:
                    raise PlanViewMismatch
                children = elements[lane.line]
                lanes.append(((lane.id, lane.type, lane.level, lane.predecessor, lane.successor),
                              (lane.heights, lane.road_marks, lane.records), tag_lines(lane.line), lane.attrib))
                cubic_records.append((tuple(cubic_record[c] for c in children.iterchildren("width")),
                                      tuple(cubic_record[c] for c in children.iterchildren("border"))))
            recipes.append((section.s0, tag_lines(section.line), section.attrib, tuple(lanes), tuple(cubic_records)))
        return tuple(cubic_record[e] for e in root.iterchildren("laneOffset")), tuple(recipes)

    def lane_sections(self, lanes_element) -> tuple[LaneSection, ...]:
        sections = []
        for element in self.children(lanes_element, "laneSection"):
            s0 = self.number(element, "s", 0.0)
            lanes = []
            groups = {}
            for child in element:  # one pass; the first <left>, <center> and <right> count, in this order
                if child.tag in _LANE_GROUPS and child.tag not in groups:
                    groups[child.tag] = child
            for group in _LANE_GROUPS:
                group_element = groups.get(group)
                if group_element is None:
                    continue
                for lane_element in group_element.iterchildren("lane"):
                    lanes.append(self.lane(lane_element, s0))
            sections.append(LaneSection(
                s0, tuple(lanes), element.get("singleSide"), self.line(element), self.shared_attrib(element),
                self.unknown(element, {"left", "center", "right"})))
        sections.sort(key=lambda section: section.s0)
        return tuple(sections)

    def warn_zero_length(self, sections: tuple[LaneSection, ...]) -> None:
        # zero-length lane sections are legal but carry no surface: keep them, evaluation skips them
        for first, second in pairwise(sections):
            if second.s0 - first.s0 <= 0:
                self.warnings.append(Diagnostic(f"zero-length lane section at s={first.s0:g}; tolerated",
                                                first.line, self.road_id, "laneSection"))

    def lane(self, element, section_s0: float) -> Lane:
        lane_id = self.lane_id(element)
        predecessor = successor = None
        widths, borders, heights, marks, records, unknown = [], [], [], [], [], []
        # one pass over the children: lanes are the most numerous element of a map
        for child in element:
            tag = child.tag
            if tag == "width":
                widths.append(self.cubic(child, "sOffset", section_s0))
            elif tag == "roadMark":
                marks.append(self.road_mark(child, section_s0))
            elif tag == "link":
                p = next(child.iterchildren("predecessor"), None)
                n = next(child.iterchildren("successor"), None)
                predecessor = self.lane_id(p) if p is not None else None
                successor = self.lane_id(n) if n is not None else None
            elif tag == "border":
                borders.append(self.cubic(child, "sOffset", section_s0))
            elif tag == "height":
                heights.append(LaneHeight(section_s0 + self.number(child, "sOffset", 0.0),
                                          self.number(child, "inner", 0.0), self.number(child, "outer", 0.0)))
            elif tag in _LANE_RECORDS:
                records.append(self.lane_record(child, tag, section_s0))
            elif isinstance(tag, str):
                unknown.append(_verbatim(child))
        level = element.get("level", "false").lower() in ("true", "1")
        return Lane(
            lane_id, self.word(element, "type", "none"), level, predecessor, successor,
            self.profiles.profile(widths, extend_first=True), self.profiles.profile(borders, extend_first=True),
            tuple(heights), self.shared_tuple(marks), self.shared_tuple(records), self.line(element), self.shared_attrib(element),
            tuple(unknown),
        )

    def shared_tuple(self, items: list) -> tuple:
        """A tuple of the items, one for every list of the same objects: a city's lanes mostly have the same
        (shared) road mark and speed record, and a tuple each would cost more than the objects they share."""
        if not items:
            return ()
        key = tuple(map(id, items))  # the items are kept alive by the tuple stored: their ids stay theirs
        found = self.tuples.get(key)
        if found is None:
            found = self.tuples[key] = tuple(items)
        return found

    def lane_id(self, element) -> int:
        """@id of a lane or a lane link: a short integer as written ("-1") directly -- what ``integer`` gives for
        it too -- anything else through ``integer`` (its checks and one-line errors)."""
        raw = element.get("id")
        if raw is not None and len(raw) <= 6:
            try:
                return int(raw)
            except ValueError:
                pass
        return self.integer(element, "id", required=True)

    def lane_record(self, element, tag: str, section_s0: float) -> LaneRecord:
        """A speed, access, ... record; one for all that are the same (a city's lanes share a few speeds)."""
        if len(element):
            return self.read_lane_record(element, tag, section_s0)
        key = (tag, section_s0.hex(), tuple(element.items()))
        record = self.records.get(key)
        if record is None:
            record = self.records[key] = self.read_lane_record(element, tag, section_s0)
        return record

    def read_lane_record(self, element, tag: str, section_s0: float) -> LaneRecord:
        return LaneRecord(tag, section_s0 + self.number(element, "sOffset", 0.0), self.shared_attrib(element),
                          tuple(_verbatim(c) for c in element if isinstance(c.tag, str)))

    def road_mark(self, element, section_s0: float) -> RoadMark:
        if len(element):
            return self.read_road_mark(element, section_s0)
        # a mark without children is a function of its attributes and the section's start: a city's marks are a
        # few (solid, broken, 0.13 m, from the section's start), read once each and shared
        key = (section_s0.hex(), tuple(element.items()))
        mark = self.marks.get(key)
        if mark is None:
            mark = self.marks[key] = self.read_road_mark(element, section_s0)
        return mark

    def read_road_mark(self, element, section_s0: float) -> RoadMark:
        type_element = self.child(element, "type")
        explicit_element = self.child(element, "explicit")
        lines, explicit, type_name, type_width = (), False, None, None
        source = type_element if type_element is not None else explicit_element
        if source is not None:
            explicit = source is explicit_element
            lines = tuple(
                RoadMarkLine(self.number(line, "length", 0.0), self.number(line, "space", 0.0),
                             self.number(line, "tOffset", 0.0), self.number(line, "sOffset", 0.0),
                             self.number(line, "width"), self.word(line, "rule"), self.word(line, "color"),
                             self.shared_attrib(line))
                for line in self.children(source, "line"))
            if type_element is not None:
                type_name = self.word(type_element, "name")
                type_width = self.number(type_element, "width")
        return RoadMark(
            section_s0 + self.number(element, "sOffset", 0.0), self.word(element, "type", "none"), self.word(element, "weight"),
            self.word(element, "color", "standard"), self.number(element, "width"), self.word(element, "laneChange"),
            self.number(element, "height"), self.word(element, "material"), type_name, type_width, lines, explicit,
            self.shared_attrib(element), self.unknown(element, {"type", "explicit"}),
        )

    def road_object(self, element) -> RoadObject:
        repeats = tuple(self.repeat(r) for r in self.children(element, "repeat"))
        outline_elements = self.children(element, "outline")
        outlines_group = self.child(element, "outlines")
        if outlines_group is not None:
            outline_elements += self.children(outlines_group, "outline")
        outlines = tuple(self.outline(o) for o in outline_elements)
        return RoadObject(
            id=element.get("id", ""), s=self.number(element, "s", 0.0), t=self.number(element, "t", 0.0),
            type=element.get("type", "none"), name=element.get("name", ""),
            z_offset=self.number(element, "zOffset", 0.0), hdg=self.number(element, "hdg", 0.0),
            pitch=self.number(element, "pitch", 0.0), roll=self.number(element, "roll", 0.0),
            length=self.number(element, "length"), width=self.number(element, "width"),
            height=self.number(element, "height"), radius=self.number(element, "radius"),
            orientation=element.get("orientation", "none"), repeats=repeats, outlines=outlines,
            line=self.line(element), attrib=self.attrib(element),
            extra_xml=self.unknown(element, {"repeat", "outline", "outlines"}),
        )

    def repeat(self, element) -> ObjectRepeat:
        n = self.number
        return ObjectRepeat(
            n(element, "s", 0.0), n(element, "length", 0.0), n(element, "distance", 0.0),
            n(element, "tStart", 0.0), n(element, "tEnd", 0.0), n(element, "zOffsetStart", 0.0),
            n(element, "zOffsetEnd", 0.0), n(element, "heightStart"), n(element, "heightEnd"),
            n(element, "widthStart"), n(element, "widthEnd"), n(element, "lengthStart"), n(element, "lengthEnd"),
            n(element, "radiusStart"), n(element, "radiusEnd"), self.attrib(element),
        )

    def outline(self, element) -> Outline:
        corners = []
        for corner in element:
            tag = _local(corner.tag)
            if tag == "cornerLocal":
                corners.append(OutlineCorner(tag, self.number(corner, "u", 0.0), self.number(corner, "v", 0.0),
                                             self.number(corner, "z", 0.0), self.number(corner, "height", 0.0),
                                             self.attrib(corner)))
            elif tag == "cornerRoad":
                corners.append(OutlineCorner(tag, self.number(corner, "s", 0.0), self.number(corner, "t", 0.0),
                                             self.number(corner, "dz", 0.0), self.number(corner, "height", 0.0),
                                             self.attrib(corner)))
        closed = element.get("closed", "true").lower() in ("true", "1")
        return Outline(tuple(corners), closed, self.attrib(element))

    def signal(self, element) -> Signal:
        return Signal(
            id=element.get("id", ""), s=self.number(element, "s", 0.0), t=self.number(element, "t", 0.0),
            dynamic=element.get("dynamic", "no").lower() in ("yes", "true"),
            orientation=element.get("orientation", "+"), z_offset=self.number(element, "zOffset", 0.0),
            country=element.get("country"), type=element.get("type", "-1"), subtype=element.get("subtype", "-1"),
            value=self.number(element, "value"), unit=element.get("unit"), name=element.get("name", ""),
            height=self.number(element, "height"), width=self.number(element, "width"),
            h_offset=self.number(element, "hOffset", 0.0), pitch=self.number(element, "pitch", 0.0),
            roll=self.number(element, "roll", 0.0), line=self.line(element), attrib=self.attrib(element),
            extra_xml=tuple(_verbatim(c) for c in element if isinstance(c.tag, str)),
        )

    def signal_reference(self, element) -> SignalReference:
        return SignalReference(element.get("id", ""), self.number(element, "s", 0.0), self.number(element, "t", 0.0),
                               element.get("orientation", "+"), self.attrib(element),
                               tuple(_verbatim(c) for c in element if isinstance(c.tag, str)))

    # -- junctions and controllers ---------------------------------------------------------------------------
    def junction(self, element) -> Junction:
        self.road_id = None
        connections = []
        for c in self.children(element, "connection"):
            links = tuple(LaneLink(self.integer(link, "from", required=True), self.integer(link, "to", required=True))
                          for link in self.children(c, "laneLink"))
            connections.append(Connection(
                c.get("id", ""), c.get("incomingRoad", ""), c.get("connectingRoad", c.get("linkedRoad", "")),
                c.get("contactPoint", "start"), links, self.attrib(c), self.unknown(c, {"laneLink"})))
        controllers = tuple(JunctionController(c.get("id", ""), c.get("type"), self.integer(c, "sequence"))
                            for c in self.children(element, "controller"))
        return Junction(element.get("id", ""), element.get("name", ""), element.get("type", "default"),
                        tuple(connections), controllers, self.line(element), self.attrib(element),
                        self.unknown(element, {"connection", "controller"}))

    def controller(self, element) -> Controller:
        self.road_id = None
        return Controller(element.get("id", ""), element.get("name", ""), self.integer(element, "sequence"),
                          tuple(c.get("signalId", "") for c in self.children(element, "control")),
                          self.attrib(element), self.unknown(element, {"control"}))

    def check_links(self, roads: list[Road], junctions: list[Junction]) -> None:
        """Dangling links become warnings with the road id: the map still loads."""
        road_ids = {road.id for road in roads}
        junction_ids = {junction.id for junction in junctions}
        for road in roads:
            for name, link in (("predecessor", road.predecessor), ("successor", road.successor)):
                if link is None:
                    continue
                known = road_ids if link.element_type == "road" else junction_ids
                if link.element_id not in known:
                    self.warnings.append(Diagnostic(
                        f"{name} links to missing {link.element_type} {link.element_id}", road.line, road.id, "link"))
        for junction in junctions:
            for connection in junction.connections:
                for road_id in (connection.incoming_road, connection.connecting_road):
                    if road_id and road_id not in road_ids:
                        self.warnings.append(Diagnostic(
                            f"junction {junction.id} connection {connection.id} names missing road {road_id}",
                            junction.line, None, "connection"))
