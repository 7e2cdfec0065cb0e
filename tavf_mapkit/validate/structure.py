"""Structure rules: the raw document -- root, header, version, required elements and attributes, numbers,
ascending s, element names. They need the XML itself (line numbers, order, spelling), not the loaded map.

They see the document in parts (validate/document.py): ``ctx.root`` holds the current part's top-level elements,
``ctx.part.outline`` the root, headers and first element of the whole document. A rule runs once per part; what it
can only say of the whole document it says on the last part (``ctx.part.last``)."""

from __future__ import annotations

import itertools
import math
from functools import cache

import numpy as np
from lxml import etree

from tavf_mapkit.validate.finding import ERROR, WARNING, Hit
from tavf_mapkit.validate.registry import rule
from tavf_mapkit.validate.schema import schema_hits

_CUBIC = ("a", "b", "c", "d")
_PARAM_POLY3 = ("aU", "bU", "cU", "dU", "aV", "bV", "cV", "dV")
_GEOMETRY_SHAPES = ("line", "arc", "spiral", "poly3", "paramPoly3")

#: path from the root -> (required attributes, numeric attributes, attributes that must be >= 0)
ELEMENTS: dict[str, tuple[tuple[str, ...], tuple[str, ...], tuple[str, ...]]] = {
    "header": ((), ("north", "south", "east", "west"), ()),
    "header/offset": ((), ("x", "y", "z", "hdg"), ()),
    "road": (("id", "length"), ("length",), ("length",)),
    "road/link/predecessor": (("elementType", "elementId"), (), ()),
    "road/link/successor": (("elementType", "elementId"), (), ()),
    "road/type": (("s", "type"), ("s",), ("s",)),
    "road/planView/geometry": (("s", "x", "y", "hdg", "length"), ("s", "x", "y", "hdg", "length"), ("s", "length")),
    "road/planView/geometry/arc": (("curvature",), ("curvature",), ()),
    "road/planView/geometry/spiral": (("curvStart", "curvEnd"), ("curvStart", "curvEnd"), ()),
    "road/planView/geometry/poly3": (_CUBIC, _CUBIC, ()),
    "road/planView/geometry/paramPoly3": (_PARAM_POLY3, _PARAM_POLY3, ()),
    "road/elevationProfile/elevation": (("s",) + _CUBIC, ("s",) + _CUBIC, ("s",)),
    "road/lateralProfile/superelevation": (("s",) + _CUBIC, ("s",) + _CUBIC, ("s",)),
    "road/lateralProfile/shape": (("s", "t") + _CUBIC, ("s", "t") + _CUBIC, ("s",)),
    "road/lanes/laneOffset": (("s",) + _CUBIC, ("s",) + _CUBIC, ("s",)),
    "road/lanes/laneSection": (("s",), ("s",), ("s",)),
    "road/lanes/laneSection/*/lane": (("id",), ("id",), ()),
    "road/lanes/laneSection/*/lane/link/predecessor": (("id",), ("id",), ()),
    "road/lanes/laneSection/*/lane/link/successor": (("id",), ("id",), ()),
    "road/lanes/laneSection/*/lane/width": (("sOffset",) + _CUBIC, ("sOffset",) + _CUBIC, ("sOffset",)),
    "road/lanes/laneSection/*/lane/border": (("sOffset",) + _CUBIC, ("sOffset",) + _CUBIC, ("sOffset",)),
    "road/lanes/laneSection/*/lane/roadMark": (("sOffset",), ("sOffset", "width", "height"), ("sOffset",)),
    "road/lanes/laneSection/*/lane/height": (("sOffset",), ("sOffset", "inner", "outer"), ("sOffset",)),
    "road/lanes/laneSection/*/lane/speed": (("sOffset", "max"), ("sOffset",), ("sOffset",)),
    "road/objects/object": (("id", "s", "t"), ("s", "t", "zOffset", "hdg", "pitch", "roll", "length", "width",
                                               "height", "radius"), ("s",)),
    "road/signals/signal": (("id", "s", "t"), ("s", "t", "zOffset", "hOffset", "pitch", "roll", "height",
                                               "width"), ("s",)),
    "road/signals/signalReference": (("id", "s", "t"), ("s", "t"), ("s",)),
    "junction": (("id",), (), ()),
    "junction/connection": (("id", "incomingRoad"), (), ()),
    "junction/connection/laneLink": (("from", "to"), ("from", "to"), ()),
    "controller": (("id",), (), ()),
}

#: every element name ASAM OpenDRIVE 1.1-1.8 defines (children of <userData> are free-form and not checked)
_KNOWN_ELEMENT_WORDS = """
OpenDRIVE header geoReference offset userData include dataQuality error rawData license defaultRegulations
road link predecessor successor neighbor type speed planView geometry line arc spiral poly3 paramPoly3
elevationProfile elevation lateralProfile superelevation crossfall shape lanes laneOffset laneSection left center
right lane width border roadMark sway explicit height material visibility access rule objects object repeat
outline outlines cornerRoad cornerLocal cornerInertial cornerRelative cornerReference validity laneValidity
parkingSpace marking markings borders bridge tunnel objectReference skeleton polyline vertexRoad vertexLocal
signals signal signalReference dependency reference positionRoad positionInertial staticBoard vmsBoard
displayArea sign semantics priority prohibited warning routing streetname parking tourist supplementaryAllows
supplementaryDistance supplementaryEnvironment supplementaryExplanatory supplementaryProhibits
supplementaryTime speed lane value unit surface CRG railroad switch mainTrack sideTrack partner station
platform segment junction connection laneLink controller control junctionGroup junctionReference boundary
crossPath startLaneLink endLaneLink elevationGrid roadSection roadRegulations signalRegulations
vmsBoardReference vmsGroup constant linear quadratic cubic coefficients crossSectionSurface surfaceStrips strip
tOffset
"""
KNOWN_ELEMENTS = frozenset(_KNOWN_ELEMENT_WORDS.split())


def _road_of(element) -> str | None:
    if element.tag == "road":
        return element.get("id")
    for ancestor in element.iterancestors("road"):
        return ancestor.get("id")
    return None


def _float(raw: str | None) -> float | None:
    try:
        return float(raw) if raw is not None else None
    except ValueError:
        return None


@rule("structure.readable", ERROR, needs="xml",
      summary="The document is an OpenDRIVE map the reader can interpret (when this fails, map rules are skipped).",
      why="A consumer that cannot read the map cannot use any of it; the message says where reading stopped.")
def readable(ctx, rule):
    error = ctx.notes.get("reader_error")
    if error is not None:
        yield Hit(f"cannot be read as OpenDRIVE: {error.message}", road=error.road, line=error.line)


@rule("structure.root", ERROR, needs="xml",
      summary="The root element is <OpenDRIVE>.",
      why="Every OpenDRIVE consumer starts from this element; anything else is not an OpenDRIVE file.")
def root_element(ctx, rule):
    root = ctx.part.outline.root
    if ctx.part.last and root.tag != "OpenDRIVE":
        yield Hit(f"root element is <{root.tag}>, expected <OpenDRIVE>", line=ctx.line(root))


@rule("structure.header", ERROR, needs="xml",
      summary="Exactly one <header>, the first child of <OpenDRIVE>, with integer @revMajor and @revMinor.",
      why="The header carries the version (which rules apply) and the georeference (where the map lies).")
def header(ctx, rule):
    if not ctx.part.last:
        return
    outline = ctx.part.outline
    headers = outline.headers
    if not headers:
        yield Hit("no <header>", line=ctx.line(outline.root))
        return
    for extra in headers[1:]:
        yield Hit("more than one <header>", line=ctx.line(extra))
    first = outline.first
    if first is not headers[0]:
        yield Hit(f"<header> must be the first child of <OpenDRIVE>, found <{first.tag}> first", line=ctx.line(first))
    for name in ("revMajor", "revMinor"):
        raw = headers[0].get(name)
        if raw is None:
            yield Hit(f"<header> has no @{name}", line=ctx.line(headers[0]))
        elif not raw.strip().isdigit():
            yield Hit(f"<header> @{name}={raw!r} is not a non-negative integer", line=ctx.line(headers[0]))


@rule("structure.version", WARNING, needs="xml",
      summary="The version is OpenDRIVE 1.4 to 1.8 (revMajor 1, revMinor 4..8).",
      why="The rules, the schema and the reader cover 1.4-1.8; other versions are checked as if they were 1.4-1.8.")
def version(ctx, rule):
    header = ctx.part.outline.header if ctx.part.last else None
    if header is None:
        return
    major, minor = header.get("revMajor", ""), header.get("revMinor", "")
    if not (major.strip().isdigit() and minor.strip().isdigit()):
        return  # structure.header reports it
    if int(major) != 1 or not 4 <= int(minor) <= 8:
        yield Hit(f"OpenDRIVE {int(major)}.{int(minor)} is outside 1.4-1.8; checked with 1.4-1.8 rules",
                  line=ctx.line(header))


@rule("structure.required-element", ERROR, needs="xml",
      summary="Every road has a <planView> with geometries (each with one shape element) and <lanes> with lane "
              "sections; the document has at least one road.",
      why="Without them a road has no position or no drivable surface; readers skip or invent what is missing.")
def required_elements(ctx, rule):
    if ctx.part.last and not ctx.part.outline.roads:
        yield Hit("the document has no <road>", line=ctx.line(ctx.part.outline.root))
    for road in ctx.root.iterfind("road"):
        road_id, line = road.get("id"), ctx.line(road)
        geometries = road.findall("planView/geometry")
        if not geometries:
            yield Hit("road has no <planView> geometry", road=road_id, line=line)
        for geometry in geometries:
            shapes = [child.tag for child in geometry if isinstance(child.tag, str) and child.tag != "userData"]
            known = [tag for tag in shapes if tag in _GEOMETRY_SHAPES]
            if len(known) != 1:
                what = ", ".join(f"<{t}>" for t in shapes) or "nothing"
                yield Hit(f"<geometry> at s={geometry.get('s')} must hold exactly one of line, arc, spiral, poly3, "
                          f"paramPoly3; it holds {what}", road=road_id, line=ctx.line(geometry))
        if not road.findall("lanes/laneSection"):
            yield Hit("road has no <lanes>/<laneSection>", road=road_id, line=line)
        for section in road.iterfind("lanes/laneSection"):
            if section.find("center/lane") is None:
                yield Hit(f"lane section at s={section.get('s')} has no centre lane", road=road_id,
                          line=ctx.line(section))


@cache
def _xpath(expression: str) -> etree.XPath:
    return etree.XPath(expression, smart_strings=False)


def _bad_number(raw: str, nonnegative: bool) -> str | None:
    try:
        value = float(raw)
    except ValueError:
        return "is not a finite number"
    if not math.isfinite(value):
        return "is not a finite number"
    return "is negative" if nonnegative and value < 0 else None


def _attribute_problems(ctx):
    """(required-attribute hits, number hits) of the whole document on the last part, else nothing yet. XPath in
    libxml2 finds the elements of each path in a part once; all values of one attribute are converted in one numpy
    call, and only a failing attribute is searched for its culprits. Hits are ordered as one pass over the whole
    document would order them: by path, attribute, then document order (part, place in the part)."""
    cache = ctx.notes.setdefault("_attribute_problems", {"part": None, "missing": [], "number": []})
    part = ctx.part.index
    if cache["part"] != part:
        cache["part"] = part
        _attribute_problems_of_part(ctx, part, cache["missing"], cache["number"])
    if not ctx.part.last:
        return [], []
    return [hit for _, hit in sorted(cache["missing"], key=lambda item: item[0])], \
        [hit for _, hit in sorted(cache["number"], key=lambda item: item[0])]


def _attribute_problems_of_part(ctx, part: int, missing_hits: list, number_hits: list) -> None:
    """Append (order key, hit) of the current part's missing attributes and bad numbers."""
    root = ctx.root
    for p, (path, (required, numeric, nonnegative)) in enumerate(ELEMENTS.items()):
        elements = _xpath(path)(root)
        if not elements:
            continue
        # each attribute read once per element (a region's part holds hundreds of thousands of geometries);
        # only a path where one is missing or a number fails is walked again to find the culprits
        values = {name: [element.get(name) for element in elements] for name in dict.fromkeys(required + numeric)}
        for i, name in enumerate(required):
            if None not in values[name]:
                continue
            for k, element in enumerate(elements):
                if element.get(name) is not None:
                    continue
                missing = [m for m in required if element.get(m) is None]
                if missing[0] == name:  # report each element once, naming everything it lacks
                    missing_hits.append(((p, i, part, k), Hit(
                        f"<{element.tag}> lacks required " + ", ".join(f"@{m}" for m in missing),
                        road=_road_of(element), line=ctx.line(element))))
        for i, name in enumerate(numeric):
            present = values[name]
            if None in present:
                present = [value for value in present if value is not None]
            if not present:
                continue
            try:
                array = np.array(present, dtype=float)
                fine = bool(np.all(np.isfinite(array))) and (name not in nonnegative or bool(np.all(array >= 0)))
            except ValueError:
                fine = False
            if fine:
                continue
            for k, element in enumerate(elements):
                raw = element.get(name)
                problem = _bad_number(raw, name in nonnegative) if raw is not None else None
                if problem:
                    number_hits.append(((p, i, part, k), Hit(f"<{element.tag}> @{name}={raw!r} {problem}",
                                                             road=_road_of(element), line=ctx.line(element))))
        del values
    after = len(ELEMENTS)  # these come after every path's, as in one pass
    for k, element in enumerate(_xpath("junction/connection[not(@connectingRoad) and not(@linkedRoad)]")(root)):
        name = "linkedRoad" if element.getparent().get("type") == "direct" else "connectingRoad"
        missing_hits.append(((after, 0, part, k), Hit(f"<connection> lacks required @{name}", line=ctx.line(element))))


@rule("structure.required-attribute", ERROR, needs="xml",
      summary="Attributes the standard requires are present (e.g. road @id/@length, geometry @s/@x/@y/@hdg/@length, "
              "lane @id, width @sOffset/@a/@b/@c/@d, link @elementType/@elementId).",
      why="A missing attribute is silently replaced by a reader's default (often 0), which moves or breaks the road.")
def required_attributes(ctx, rule):
    return _attribute_problems(ctx)[0]


@rule("structure.number", ERROR, needs="xml",
      summary="Numeric attributes parse as finite numbers; lengths and s values are not negative.",
      why="NaN, infinity or text where a number belongs make every computed position meaningless.")
def numbers(ctx, rule):
    return _attribute_problems(ctx)[1]


_ORDERED = (("planView/geometry", "s"), ("elevationProfile/elevation", "s"),
            ("lateralProfile/superelevation", "s"), ("lanes/laneOffset", "s"), ("lanes/laneSection", "s"))
_LANE_ORDERED = (("width", "sOffset"), ("border", "sOffset"), ("roadMark", "sOffset"), ("height", "sOffset"))


def _descending(elements, attribute):
    """Elements whose @attribute is smaller than the one before (unparseable values are someone else's)."""
    previous = None
    for element in elements:
        value = _float(element.get(attribute))
        if value is None or not math.isfinite(value):
            continue
        if previous is not None and value < previous[0]:
            yield element, value, previous[0]
        previous = (value, element)


@rule("structure.s-order", ERROR, needs="xml",
      summary="Records keyed by s appear in ascending s: geometries, elevation, superelevation, lane offsets, lane "
              "sections, and per lane width, border, road-mark and height records.",
      why="The standard requires ascending order; readers that do not sort (many do not) evaluate the wrong record.")
def s_order(ctx, rule):
    for road in ctx.root.iterfind("road"):
        road_id = road.get("id")
        for path, attribute in _ORDERED:
            for element, value, before in _descending(road.iterfind(path), attribute):
                yield Hit(f"<{element.tag}> @{attribute}={value:g} comes after @{attribute}={before:g}",
                          road=road_id, s=value, line=ctx.line(element))
        for lane in road.iterfind("lanes/laneSection/*/lane"):
            lane_id = _float(lane.get("id"))
            for tag, attribute in _LANE_ORDERED:
                for element, value, before in _descending(lane.iterfind(tag), attribute):
                    yield Hit(f"<{tag}> @{attribute}={value:g} comes after @{attribute}={before:g}", road=road_id,
                              lane=int(lane_id) if lane_id is not None and lane_id.is_integer() else None,
                              line=ctx.line(element))


@rule("structure.unknown-element", WARNING, needs="xml",
      summary="Every element name is one ASAM OpenDRIVE 1.1-1.8 defines (children of <userData> are free).",
      why="A misspelt element (e.g. <geomtry>) is ignored by every reader: the data it carries is lost silently.")
def unknown_elements(ctx, rule):
    # the root once, before its first part (document order); ctx.root only stands for it
    elements = ctx.root.iterdescendants()
    if ctx.part.index == 0:
        elements = itertools.chain((ctx.part.outline.root,), elements)
    for element in elements:
        tag = element.tag
        if not isinstance(tag, str) or tag in KNOWN_ELEMENTS:
            continue
        if any(True for _ in element.iterancestors("userData")):
            continue
        parent = element.getparent()
        inside = f" inside <{parent.tag}>" if parent is not None else ""
        yield Hit(f"unknown element <{tag}>{inside}", road=_road_of(element), line=ctx.line(element))


@rule("structure.schema", WARNING, needs="xml",
      summary="The document validates against the official XSD of its version, when that schema is at hand "
              "(see 'Schema validation' below; XSD 1.1 schemas, i.e. 1.8, cannot be checked with libxml2).",
      why="The schema is the standard's formal contract; a violation (e.g. an <offset> in a 1.4 file, which 1.4 "
          "readers ignore) means some readers will reject or misread the file.")
def schema(ctx, rule):
    yield from schema_hits(ctx)
