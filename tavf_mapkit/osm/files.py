"""Which files osmium reads, and osmium's errors turned into one-line InputErrors."""

from __future__ import annotations

import re
from contextlib import contextmanager
from pathlib import Path

from tavf_mapkit.errors import InputError

# osmium picks the reader from the name; we accept what it reads and refuse the rest before it tries.
OSM_SUFFIXES = (".osm", ".osm.pbf", ".pbf", ".osm.bz2", ".osm.gz", ".osm.xml", ".osm.xml.gz", ".osm.xml.bz2")
_XML_ERROR = re.compile(r"XML parsing error at line (\d+), column (\d+): (.*)")


def is_osm_file(path: str | Path) -> bool:
    return str(path).lower().endswith(OSM_SUFFIXES)


def require_osm_name(path: str | Path, role: str = "input") -> None:
    """Refuse names osmium would not know how to read or write."""
    if not is_osm_file(path):
        raise InputError(f"{role} must end in one of {', '.join(OSM_SUFFIXES)}", file=str(path))


def require_readable(path: str | Path) -> Path:
    """The path, if it is an existing regular file we can open; otherwise a one-line InputError."""
    path = Path(path)
    if not path.exists():
        raise InputError("file not found", file=str(path))
    if path.is_dir():
        raise InputError("is a directory, expected a file", file=str(path))
    try:
        with path.open("rb"):
            pass
    except OSError as error:
        raise InputError(f"cannot read: {error.strerror}", file=str(path)) from None
    return path


@contextmanager
def osmium_errors(path: str | Path):
    """Translate osmium's RuntimeErrors (XML, PBF, compression) and bad node coordinates into InputErrors naming
    the file and line."""
    import osmium

    name = str(path)
    try:
        yield
    except osmium.InvalidLocationError as error:  # not a RuntimeError: a node's lat/lon is not a number
        raise InputError(f"a node has an invalid location ({error})", file=name) from None
    except RuntimeError as error:
        raise _input_error(str(error), name) from None


def _input_error(message: str, name: str) -> InputError:
    if "XML entities are not supported" in message:
        # libosmium's expat reader refuses entity declarations outright, so nothing is ever expanded.
        return InputError("refused: the file declares XML entities (<!ENTITY>); mapkit never expands them",
                          file=name)
    match = _XML_ERROR.search(message)
    if match:
        line, _column, what = match.groups()
        hint = " (truncated file?)" if what in ("no element found", "unclosed token") else ""
        return InputError(f"not well-formed OSM XML: {what}{hint}", file=name, line=int(line))
    if message.startswith("PBF error"):
        return InputError(f"not a valid OSM PBF file ({message})", file=name)
    if "gzip" in message.lower() or "bzip2" in message.lower():
        return InputError(f"cannot decompress ({message})", file=name)
    return InputError(f"cannot read OSM data: {message}", file=name)
