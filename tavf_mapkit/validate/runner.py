"""Run the rule catalogue on a file (structure rules see the raw XML) or on an already loaded map."""

from __future__ import annotations

from pathlib import Path

from tavf_mapkit.errors import InputError, MapkitError
from tavf_mapkit.validate.context import ValidationContext
from tavf_mapkit.validate.finding import ERROR, WARNING, Finding
from tavf_mapkit.validate.registry import select_rules
from tavf_mapkit.validate.report import ValidationReport
from tavf_mapkit.xmlsafe import parse_safe, read_xml_source


def _strip_namespace(root) -> None:
    """OpenDRIVE has no namespace; some writers add one anyway. Plain tags keep the rules simple."""
    if not isinstance(root.tag, str) or root.tag[0] != "{":
        return
    for node in root.iter():
        if isinstance(node.tag, str) and node.tag[0] == "{":
            node.tag = node.tag.rsplit("}", 1)[-1]


def validate_file(path: str | Path, rules=None, strict: bool = False,
                  schema_dir: str | Path | None = None, odr=None) -> ValidationReport:
    """Validate an OpenDRIVE file. ``rules``: ids or families (``"geometry,topology.contact-gap"``), None = all.
    ``odr``: the file already loaded (``load_opendrive(path)``), so a caller that has it does not read it twice.

    Raises InputError (exit code 2) only when the file is missing or not well-formed XML; everything else,
    including a document the reader refuses, becomes findings.
    """
    from tavf_mapkit.opendrive import load_opendrive

    name = str(path)
    source = read_xml_source(path)
    root = parse_safe(source)
    _strip_namespace(root)
    context = ValidationContext(name, None, root, source.line_offset, schema_dir)
    try:
        context.odr = load_opendrive(path) if odr is None else odr
    except InputError as error:
        context.notes["reader_error"] = error
    header = root.find("header")
    version = None
    if header is not None:
        version = f"{header.get('revMajor', '?')}.{header.get('revMinor', '?')}"
    return _run(context, select_rules(rules), strict, version)


def validate_map(odr, rules=None, strict: bool = False) -> ValidationReport:
    """Validate an already loaded OpenDriveMap (map rules only: structure rules need the raw document)."""
    context = ValidationContext(odr.source or "<map>", odr)
    return _run(context, select_rules(rules), strict, odr.header.revision)


def _run(context: ValidationContext, rules, strict: bool, version: str | None) -> ValidationReport:
    findings, ran, skipped = [], [], []
    for rule in rules:
        available = context.root is not None if rule.needs == "xml" else context.odr is not None
        if not available:
            skipped.append(rule.id)
            continue
        ran.append(rule.id)
        severity = ERROR if strict and rule.severity == WARNING else rule.severity
        try:
            for hit in rule.check(context, rule):
                findings.append(Finding(rule.id, severity, hit.road, hit.lane, hit.s, hit.line, hit.message))
        except MapkitError as error:
            # a rule that would sample an implausible road (or over the map's budget) reports why it could not
            # check, and the other rules still run: a validator's job is to list what is wrong
            findings.append(Finding(rule.id, ERROR, error.road, None, None, error.line,
                                    f"not checked: {error.message}"))
    notes = {key: value for key, value in context.notes.items() if not key.startswith("_") and key != "reader_error"}
    return ValidationReport(context.name, tuple(findings), tuple(ran), strict, version, notes, tuple(skipped))
