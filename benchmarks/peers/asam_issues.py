"""Where ASAM's quality checker found its issues: the roads of every issue of an ``.xqar`` result, per checker, so
that they can be compared with the roads our validator's matching rule names (docs/validation-rules.md, "ASAM
quality checker").

    >>> roads = issue_roads(folder / "map.xqar", "map.xodr")   # {"road_linkage_is_junction_needed": {"12", ...}}

An issue points at XML elements (XPath). The road of an element is the <road> it lies in; a junction <connection>
stands for its connecting road, except where the rule is about the incoming road. Issues without an XML location
are counted under the road None.
"""

from __future__ import annotations

import re
from collections import defaultdict
from pathlib import Path

PREFIX = "check_asam_xodr_"
#: checkers whose <connection> locations are about the incoming road
INCOMING = {"junctions_connection_connect_road_no_incoming_road"}
#: checkers whose issue is about the road the others link to, not the linking roads
LINKED = {"road_linkage_is_junction_needed"}


def _document(xodr: Path):
    """The document as the checker reads it: a default namespace removed (qc_opendrive does the same)."""
    from lxml import etree

    text = Path(xodr).read_bytes().decode("utf-8-sig")
    return etree.fromstring(re.sub(' xmlns="[^"]+"', "", text, count=1).encode(),
                            etree.XMLParser(huge_tree=True, remove_blank_text=False))


def _road_of(element, checker: str) -> str | None:
    if checker in LINKED and element.tag in ("predecessor", "successor") and element.get("elementId"):
        return element.get("elementId")
    for node in (element, *element.iterancestors()):
        if node.tag == "connection":  # or a laneLink in it
            return node.get("incomingRoad" if checker in INCOMING else "connectingRoad")
        if node.tag == "road":
            return node.get("id")
    return None


def issue_roads(xqar: Path | str, xodr: Path | str) -> dict[str, set]:
    """{checker (without the check_asam_xodr_ prefix): set of road ids} over every issue of the result. An
    issue's road is that of its first XML location (the element the rule is about)."""
    from lxml import etree

    root, result = _document(Path(xodr)), etree.parse(str(xqar)).getroot()
    tree = root.getroottree()
    found: dict[str, set] = defaultdict(set)
    for checker in result.iter("Checker"):
        name = checker.get("checkerId").replace(PREFIX, "")
        for issue in checker.iter("Issue"):
            location = next(issue.iter("XMLLocation"), None)
            elements = tree.xpath(location.get("xpath")) if location is not None else []
            found[name].add(_road_of(elements[0], name) if elements else None)
    return dict(found)
