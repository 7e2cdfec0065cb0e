"""Safe XML parsing: no entity expansion, no DTD loading, no network, tolerant of a leading comment or BOM.

Real OpenDRIVE files sometimes start with a licence comment before the XML declaration (CARLA's Town07),
which libxml2 rejects; we skip such a prolog and keep line numbers right by remembering what was skipped.
"""

from __future__ import annotations

import io
import re
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from lxml import etree

from tavf_mapkit.errors import InputError

_DECLARATION = re.compile(rb"<\?xml[\s?]")
_DOCTYPE = re.compile(rb"<!DOCTYPE", re.IGNORECASE)
_ENTITY = re.compile(rb"<!ENTITY", re.IGNORECASE)
_PROLOG_SCAN_BYTES = 1 << 16


#: bytes of a file's start that decide where its document begins and whether it is refused: a BOM, a prolog
#: scanned for the XML declaration, then the DOCTYPE's scan and its entity scan (see ``prepare_xml_bytes``)
_HEAD_BYTES = 3 + 3 * _PROLOG_SCAN_BYTES


@dataclass
class XmlSource:
    """The document to hand to the parser and how many lines were skipped before it: its bytes (``data``), or,
    for a file read by ``read_xml_source``, the file and the byte its document starts at (``data`` None): the
    parser then reads the file as it goes, so a 1.4 GB OpenDRIVE is never in memory whole beside its map."""

    data: bytes | None
    line_offset: int
    name: str
    root: object = None  # set by iterparse_safe once parsing has finished
    path: Path | None = None
    start: int = 0

    def stream(self):
        """A binary stream of the document (close it when done)."""
        if self.data is not None:
            return io.BytesIO(self.data)
        handle = _open_input(self.path)
        handle.seek(self.start)
        return handle


@contextmanager
def _input_errors(path: str | Path, expected: str):
    """A missing, unreadable or directory path as a one-line InputError."""
    name = str(path)
    try:
        yield
    except FileNotFoundError:
        raise InputError("file not found", file=name) from None
    except IsADirectoryError:
        raise InputError(f"is a directory, expected {expected}", file=name) from None
    except OSError as error:
        raise InputError(f"cannot read: {error.strerror}", file=name) from None


def _open_input(path: str | Path, expected: str = "an XML file"):
    with _input_errors(path, expected):
        return open(path, "rb")


def read_input_bytes(path: str | Path, expected: str = "an XML file") -> bytes:
    """A whole input file; a missing, unreadable or directory path becomes a one-line InputError."""
    with _input_errors(path, expected):
        return Path(path).read_bytes()


def read_xml_source(path: str | Path) -> XmlSource:
    """A file for safe parsing, read by the parser as it goes (only its head is read here); refuse DTD entity
    declarations (billion laughs, external entities)."""
    with _open_input(path) as handle, _input_errors(path, "an XML file"):
        head = handle.read(_HEAD_BYTES)
    start, line_offset = _document_start(head, str(path))
    return XmlSource(None, line_offset, str(path), path=Path(path), start=start)


def prepare_xml_bytes(data: bytes, name: str = "<bytes>") -> XmlSource:
    """Strip a BOM or comments before the XML declaration; refuse entity declarations."""
    start, line_offset = _document_start(data[:_HEAD_BYTES], name)
    return XmlSource(data[start:] if start else data, line_offset, name)


def _document_start(head: bytes, name: str) -> tuple[int, int]:
    """(byte where the document starts, lines skipped before it) of a file starting with ``head`` (at least its
    first _HEAD_BYTES): after a BOM and comments before the XML declaration. Entity declarations are refused."""
    start = 3 if head.startswith(b"\xef\xbb\xbf") else 0
    line_offset = 0
    scan = head[start:start + _PROLOG_SCAN_BYTES]
    match = _DECLARATION.search(scan)
    if match and match.start() > 0 and scan[: match.start()].strip():
        prefix = scan[: match.start()]
        if not prefix.lstrip().startswith(b"<!--"):
            raise InputError("unexpected content before the XML declaration", file=name, line=1)
        line_offset = prefix.count(b"\n")
        start += match.start()
    data = head[start:]
    doctype = _DOCTYPE.search(data[:_PROLOG_SCAN_BYTES])
    # Entity declarations are how billion-laughs and external-entity attacks work; real map files have none.
    if doctype and _ENTITY.search(data[doctype.start():doctype.start() + _PROLOG_SCAN_BYTES]):
        line = data[: doctype.start()].count(b"\n") + 1 + line_offset
        raise InputError("DTD entity declarations are not allowed (refused for safety)", file=name, line=line)
    return start, line_offset


def safe_parser(**options) -> etree.XMLParser:
    """An lxml parser that never resolves entities, never loads a DTD and never touches the network."""
    return etree.XMLParser(
        resolve_entities=False, no_network=True, load_dtd=False, dtd_validation=False, huge_tree=True,
        remove_comments=False, **options,
    )


def iterparse_safe(source: XmlSource, events=("start", "end"), tag=None, stream_filter=None):
    """lxml.iterparse over prepared bytes with the safe settings; errors become one-line InputErrors.
    ``stream_filter``: called with the document's binary stream, gives the stream the parser reads instead."""
    with source.stream() as stream:
        context = etree.iterparse(
            stream if stream_filter is None else stream_filter(stream), events=events, tag=tag, resolve_entities=False, no_network=True, load_dtd=False,
            huge_tree=True, remove_comments=True, remove_pis=True,
        )
        try:
            yield from context
            source.root = context.root
        except etree.XMLSyntaxError as error:
            line = error.lineno + source.line_offset if error.lineno else None
            message = error.msg.split(", line ")[0] if error.msg else "malformed XML"
            raise InputError(f"not well-formed XML: {message}", file=source.name, line=line) from None


def release_if_top_level(element: etree._Element) -> bool:
    """In a streaming pass, let a finished child of the document's root go together with the siblings before it
    (lxml keeps every parsed element otherwise: a region's file would become a whole tree). True if it was one."""
    parent = element.getparent()
    if parent is None or parent.getparent() is not None:
        return False
    element.clear()
    while element.getprevious() is not None:
        del parent[0]
    return True


def parse_safe(source: XmlSource) -> etree._Element:
    """Parse a whole document with the safe settings and return its root."""
    try:
        if source.data is not None:
            return etree.fromstring(source.data, safe_parser())
        with source.stream() as stream:
            return etree.parse(stream, safe_parser()).getroot()
    except etree.XMLSyntaxError as error:
        line = error.lineno + source.line_offset if error.lineno else None
        raise InputError(f"not well-formed XML: {error.msg}", file=source.name, line=line) from None
