"""Safe XML parsing: no entity expansion, no DTD loading, no network, tolerant of a leading comment or BOM.

Real OpenDRIVE files sometimes start with a licence comment before the XML declaration (CARLA's Town07),
which libxml2 rejects; we skip such a prolog and keep line numbers right by remembering what was skipped.
"""

from __future__ import annotations

import io
import re
from dataclasses import dataclass
from pathlib import Path

from lxml import etree

from tavf_mapkit.errors import InputError

_DECLARATION = re.compile(rb"<\?xml[\s?]")
_DOCTYPE = re.compile(rb"<!DOCTYPE", re.IGNORECASE)
_ENTITY = re.compile(rb"<!ENTITY", re.IGNORECASE)
_PROLOG_SCAN_BYTES = 1 << 16


@dataclass
class XmlSource:
    """The bytes to hand to the parser and how many lines were skipped before them."""

    data: bytes
    line_offset: int
    name: str
    root: object = None  # set by iterparse_safe once parsing has finished


def read_input_bytes(path: str | Path, expected: str = "an XML file") -> bytes:
    """A whole input file; a missing, unreadable or directory path becomes a one-line InputError."""
    name = str(path)
    try:
        return Path(path).read_bytes()
    except FileNotFoundError:
        raise InputError("file not found", file=name) from None
    except IsADirectoryError:
        raise InputError(f"is a directory, expected {expected}", file=name) from None
    except OSError as error:
        raise InputError(f"cannot read: {error.strerror}", file=name) from None


def read_xml_source(path: str | Path) -> XmlSource:
    """Read a file for safe parsing; refuse DTD entity declarations (billion laughs, external entities)."""
    return prepare_xml_bytes(read_input_bytes(path), str(path))


def prepare_xml_bytes(data: bytes, name: str = "<bytes>") -> XmlSource:
    """Strip a BOM or comments before the XML declaration; refuse entity declarations."""
    if data.startswith(b"\xef\xbb\xbf"):
        data = data[3:]
    line_offset = 0
    head = data[:_PROLOG_SCAN_BYTES]
    match = _DECLARATION.search(head)
    if match and match.start() > 0 and head[: match.start()].strip():
        prefix = data[: match.start()]
        if not prefix.lstrip().startswith(b"<!--"):
            raise InputError("unexpected content before the XML declaration", file=name, line=1)
        line_offset = prefix.count(b"\n")
        data = data[match.start():]
    doctype = _DOCTYPE.search(data[:_PROLOG_SCAN_BYTES])
    if doctype:
        # Entity declarations are how billion-laughs and external-entity attacks work; real map files have none.
        if _ENTITY.search(data[doctype.start():doctype.start() + _PROLOG_SCAN_BYTES]):
            line = data[: doctype.start()].count(b"\n") + 1 + line_offset
            raise InputError("DTD entity declarations are not allowed (refused for safety)", file=name, line=line)
    return XmlSource(data, line_offset, name)


def safe_parser(**options) -> etree.XMLParser:
    """An lxml parser that never resolves entities, never loads a DTD and never touches the network."""
    return etree.XMLParser(
        resolve_entities=False, no_network=True, load_dtd=False, dtd_validation=False, huge_tree=True,
        remove_comments=False, **options,
    )


def iterparse_safe(source: XmlSource, events=("start", "end"), tag=None):
    """lxml.iterparse over prepared bytes with the safe settings; errors become one-line InputErrors."""
    stream = io.BytesIO(source.data)
    context = etree.iterparse(
        stream, events=events, tag=tag, resolve_entities=False, no_network=True, load_dtd=False, huge_tree=True,
        remove_comments=True, remove_pis=True,
    )
    try:
        yield from context
        source.root = context.root
    except etree.XMLSyntaxError as error:
        line = error.lineno + source.line_offset if error.lineno else None
        message = error.msg.split(", line ")[0] if error.msg else "malformed XML"
        raise InputError(f"not well-formed XML: {message}", file=source.name, line=line) from None


def parse_safe(source: XmlSource) -> etree._Element:
    """Parse a whole document with the safe settings and return its root."""
    try:
        return etree.fromstring(source.data, safe_parser())
    except etree.XMLSyntaxError as error:
        line = error.lineno + source.line_offset if error.lineno else None
        raise InputError(f"not well-formed XML: {error.msg}", file=source.name, line=line) from None
