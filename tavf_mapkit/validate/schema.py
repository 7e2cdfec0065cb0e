"""XSD validation against the official schema of the file's version, when such a schema is at hand.

The schemas are not shipped with tavf-mapkit: ASAM's 1.6-1.8 XSDs are "distributable in accordance with the ASAM
license terms" (rights granted to ASAM licensees, not an open licence) and the 1.4H/1.5M XSDs carry a VIRES
copyright without a licence grant. A folder with the layout of the ``schema/`` folder of the PyPI package
asam-qc-opendrive (``1.4/OpenDRIVE_1.4H.xsd``, ``1.6.1/opendrive_16_core.xsd``, ...) is used when given
(``schema_dir``, ``--schema-dir`` or ``MAPKIT_OPENDRIVE_XSD``) or when that package is installed alongside.
"""

from __future__ import annotations

import importlib.util
import os
from functools import lru_cache
from pathlib import Path

from lxml import etree

from tavf_mapkit.validate.finding import Hit

ENVIRONMENT_VARIABLE = "MAPKIT_OPENDRIVE_XSD"
#: revMinor -> schema file relative to the schema folder (asam-qc-opendrive's layout)
SCHEMA_FILES = {
    1: "1.1/OpenDRIVE_1.1.xsd", 2: "1.2/OpenDRIVE_1.2.xsd", 3: "1.3/OpenDRIVE_1.3.xsd",
    4: "1.4/OpenDRIVE_1.4H.xsd", 5: "1.5/OpenDRIVE_1.5M.xsd", 6: "1.6.1/opendrive_16_core.xsd",
    7: "1.7.0/opendrive_17_core.xsd", 8: "1.8.0/OpenDRIVE_Core.xsd",
}
MAX_HITS = 200


def schema_folders(schema_dir: str | Path | None) -> list[Path]:
    """Where to look, in order: the explicit folder, $MAPKIT_OPENDRIVE_XSD, an installed asam-qc-opendrive."""
    folders = []
    if schema_dir:
        folders.append(Path(schema_dir))
    if os.environ.get(ENVIRONMENT_VARIABLE):
        folders.append(Path(os.environ[ENVIRONMENT_VARIABLE]))
    spec = importlib.util.find_spec("qc_opendrive")  # locates the package without importing it
    if spec is not None and spec.submodule_search_locations:
        folders.extend(Path(location) / "schema" for location in spec.submodule_search_locations)
    return folders


def find_schema(rev_minor: int, schema_dir: str | Path | None = None) -> Path | None:
    relative = SCHEMA_FILES.get(rev_minor)
    if relative is None:
        return None
    for folder in schema_folders(schema_dir):
        if (folder / relative).is_file():
            return folder / relative
    return None


@lru_cache(maxsize=8)
def load_schema(path: Path) -> etree.XMLSchema:
    """A compiled schema; raises etree.XMLSchemaParseError for XSD 1.1 (libxml2 knows XSD 1.0 only)."""
    parser = etree.XMLParser(resolve_entities=False, no_network=True)
    return etree.XMLSchema(etree.parse(str(path), parser))


def schema_hits(ctx):
    """On the document's last part: the schema's violations (the XSD validator needs the whole document tree,
    about ten times the file, so it is built only when a schema is at hand, and let go right after)."""
    if not ctx.part.last:
        return
    header = ctx.part.outline.header
    raw = header.get("revMinor", "") if header is not None else ""
    version = f"1.{raw.strip()}" if raw.strip().isdigit() else "unknown"
    path = find_schema(int(raw), ctx.schema_dir) if raw.strip().isdigit() else None
    if path is None:
        ctx.notes["schema"] = {"version": version, "status": "unavailable", "path": None}
        return
    try:
        schema = load_schema(path)
    except etree.XMLSchemaParseError as error:
        ctx.notes["schema"] = {"version": version, "status": f"unusable: {str(error)[:120]}", "path": str(path)}
        return
    valid, errors = _validate_document(schema, ctx.source)
    ctx.notes["schema"] = {"version": version, "status": "valid" if valid else "invalid", "path": str(path)}
    for error in errors[:MAX_HITS]:
        yield Hit(f"schema {version}: {error.message}", line=error.line + ctx.line_offset if error.line else None)
    if len(errors) > MAX_HITS:
        yield Hit(f"schema {version}: {len(errors) - MAX_HITS} more violations not listed")


def _validate_document(schema: etree.XMLSchema, source) -> tuple[bool, list]:
    """(valid, the error log's entries) of the whole document, namespaces stripped as the other rules see them.
    libxml2's streaming validation (a parser with a schema) words and places violations differently (line 0), so
    the tree is built for it."""
    from tavf_mapkit.validate.document import strip_namespace
    from tavf_mapkit.xmlsafe import parse_safe

    root = parse_safe(source)
    if isinstance(root.tag, str) and root.tag[0] == "{":
        strip_namespace(root)
    valid = schema.validate(root)
    return valid, list(schema.error_log)
