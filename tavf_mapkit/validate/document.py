"""The raw document for the structure rules, in parts: a bounded piece of the tree at a time.

A whole lxml tree takes about ten times its file (Maribor's 407 MB OpenDRIVE: 4.1 GB, three times the loaded map),
so the document is parsed incrementally: its top-level elements (header, roads, junctions, controllers) are handed
to the rules in parts of about ELEMENTS_PER_PART elements, and a part is let go once the rules have seen it. A
top-level element is never split (the rules look at a road as a whole), so memory is bounded by the part and the
largest road, not by the map. What the rules need of the whole document (its root, the headers, which element
comes first, whether there is a road) is kept in a small Outline.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field

from lxml import etree

from tavf_mapkit.errors import InputError
from tavf_mapkit.xmlsafe import XmlSource, parse_safe

#: elements (at any depth) of one part, about 50 MB of tree; a part ends only between top-level elements
ELEMENTS_PER_PART = 100_000


@dataclass
class Outline:
    """What the document-wide rules need, small whatever the map: the root element (without its children), every
    top-level <header> (whole), the first top-level element (a stand-in with its tag and line when it is not a
    header) and the number of top-level roads. Complete once the last part has been read."""

    root: etree._Element | None = None  # a childless copy: tag (namespace stripped), attributes, line
    first: etree._Element | None = None
    headers: list = field(default_factory=list)
    roads: int = 0

    @property
    def header(self):
        """The first <header>, or None."""
        return self.headers[0] if self.headers else None


@dataclass
class DocumentPart:
    """Consecutive top-level nodes of the document, in order, as children of ``root``: an element that stands for
    the document's root (its tag), so that paths from the root (``road/planView/geometry``) find this part's
    elements. ``last``: the document has been read to its end, the outline is complete."""

    root: etree._Element
    index: int
    last: bool
    outline: Outline


def strip_namespace(root) -> None:
    """OpenDRIVE has no namespace; some writers add one anyway. Plain tags keep the rules simple."""
    for node in root.iter():
        if isinstance(node.tag, str) and node.tag[0] == "{":
            node.tag = node.tag.rsplit("}", 1)[-1]


def _namespaced(element) -> bool:
    return isinstance(element.tag, str) and element.tag[0] == "{"


def document_parts(source: XmlSource, elements_per_part: int | None = None) -> Iterator[DocumentPart]:
    """The document in parts of about ``elements_per_part`` elements (default ELEMENTS_PER_PART), namespaces
    stripped when the root has one; the last part (``last``, possibly empty) comes after the whole document was
    read. A part is valid until the next one is asked for.

    A document that is not well-formed raises the InputError of ``xmlsafe.parse_safe`` (the incremental parser
    words some faults differently), after the parts before the fault.
    """
    with source.stream() as document:  # the file is read as the parts are asked for, never whole
        yield from _parts(source, document, elements_per_part or ELEMENTS_PER_PART)


def _parts(source: XmlSource, document, limit: int) -> Iterator[DocumentPart]:
    outline = Outline()
    stream = etree.iterparse(document, events=("end",), resolve_entities=False, no_network=True,
                             load_dtd=False, dtd_validation=False, huge_tree=True, remove_comments=False)
    root = None  # the document's root as the parser builds it
    strip = False
    part = None
    held = 0  # elements in the part
    waiting = 0  # elements of the top-level element that ended last: it stays in the root until the next one ends
    counted = 0  # elements ended since then
    index = 0
    try:
        for _event, element in stream:
            counted += 1
            parent = element.getparent()
            if root is None:
                root = element if parent is None else parent
                while root.getparent() is not None:
                    root = root.getparent()
                strip = _namespaced(root)
                outline.root = _stand_in(root, _plain_tag(root), root.attrib)
            if parent is not root:
                continue  # inside a top-level element, or the root's own end
            if strip:
                strip_namespace(element)
            _note(outline, element)
            if part is None:
                part = root.makeelement(outline.root.tag)
            # only the nodes before this element move on: the parser may be past its end already, and taking the
            # root's last child from under it would cut the text node it is appending to
            _move(list(element.itersiblings(preceding=True))[::-1], part)
            held, waiting, counted = held + waiting, counted, 0
            if held >= limit:
                yield DocumentPart(part, index, False, outline)
                _release(part, outline)
                part, held, index = None, 0, index + 1
    except etree.XMLSyntaxError as error:
        parse_safe(source)  # raises the whole-document parser's InputError, as validation always reported it
        line = error.lineno + source.line_offset if error.lineno else None
        raise InputError(f"not well-formed XML: {error.msg}", file=source.name, line=line) from None
    if part is None:
        part = root.makeelement(outline.root.tag)
    if strip:
        for node in root:
            strip_namespace(node)
    _move(list(root), part)
    yield DocumentPart(part, index, True, outline)
    _release(part, outline)


def _plain_tag(element) -> str:
    return element.tag.rsplit("}", 1)[-1] if _namespaced(element) else element.tag


def _stand_in(element, tag: str, attributes=None):
    """A childless element with ``element``'s line: what the outline keeps of an element it must not hold (a
    top-level element would keep its whole part alive; the root would keep its namespace until the end)."""
    copy = element.makeelement(tag, attributes)
    copy.sourceline = element.sourceline
    return copy


def _note(outline: Outline, element) -> None:
    """Record a top-level element in the outline."""
    if outline.first is None:
        outline.first = element if element.tag == "header" else _stand_in(element, element.tag)
    if element.tag == "header":
        outline.headers.append(element)
    elif element.tag == "road":
        outline.roads += 1


def _move(nodes, part) -> None:
    for node in nodes:
        part.append(node)


def _release(part, outline: Outline) -> None:
    """Take the headers out of a part the rules have seen, so that nothing keeps the rest of it alive."""
    for header in outline.headers:
        if header.getparent() is part:
            part.remove(header)
