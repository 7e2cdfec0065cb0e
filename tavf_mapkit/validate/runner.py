"""Run the rule catalogue on a file (structure rules see the raw XML) or on an already loaded map."""

from __future__ import annotations

from pathlib import Path

from tavf_mapkit.errors import InputError, MapkitError
from tavf_mapkit.memory import frozen_heap, return_freed_memory
from tavf_mapkit.validate.context import ValidationContext
from tavf_mapkit.validate.document import document_parts
from tavf_mapkit.validate.finding import ERROR, WARNING, Finding
from tavf_mapkit.validate.registry import select_rules
from tavf_mapkit.validate.report import ValidationReport
from tavf_mapkit.xmlsafe import read_xml_source

#: structure rules that report what the reader made of the document, so they run after the map is loaded
AFTER_LOAD = frozenset({"structure.readable"})


def validate_file(path: str | Path, rules=None, strict: bool = False,
                  schema_dir: str | Path | None = None, odr=None) -> ValidationReport:
    """Validate an OpenDRIVE file. ``rules``: ids or families (``"geometry,topology.contact-gap"``), None = all.
    ``odr``: the file already loaded (``load_opendrive(path)``), so a caller that has it does not read it twice.

    Raises InputError (exit code 2) only when the file is missing or not well-formed XML; everything else,
    including a document the reader refuses, becomes findings.
    """
    return validate_and_load(path, rules, strict, schema_dir, odr)[0]


def validate_and_load(path: str | Path, rules=None, strict: bool = False, schema_dir: str | Path | None = None,
                      odr=None, snapshot: str | Path | None = None):
    """``validate_file``, and the map it read: (report, OpenDriveMap or None, the reader's InputError or None).

    The structure rules see the document in parts (validate/document.py: a whole lxml tree is about ten times the
    file), never together with the map: then the file's bytes are let go and the map is loaded (unless given; from
    ``snapshot`` when that is the file's valid snapshot, opendrive/snapshot.py) for the rules that need it. ``structure.readable`` reports the reader's verdict, so it runs after the load.
    """
    from tavf_mapkit.opendrive import load_opendrive
    from tavf_mapkit.opendrive.snapshot import load_build_map

    source = read_xml_source(path)
    context = ValidationContext(str(path), None, None, source.line_offset, schema_dir)
    try:
        rules = list(select_rules(rules))
    except ValueError:
        for _part in document_parts(source):  # a file that is not XML is reported first, as it always was
            pass
        raise
    available = {rule.id: True if rule.needs == "xml" else None for rule in rules}
    document_rules = [rule for rule in rules if rule.needs == "xml" and rule.id not in AFTER_LOAD]
    found = {rule.id: [] for rule in document_rules}
    context.source = source
    del source  # the context holds the only reference to the file's bytes, so they can be let go
    for part in document_parts(context.source):
        context.root, context.part = part.root, part
        for rule in document_rules:
            found[rule.id] += _check(context, rule, strict)
        context.root = None
    header = part.outline.header
    version = None if header is None else f"{header.get('revMajor', '?')}.{header.get('revMinor', '?')}"
    context.part = context.source = part = header = None
    return_freed_memory()  # the document's memory is not reused by the map's objects unless it goes back first
    error = None
    try:
        if odr is None:
            odr = load_opendrive(path) if snapshot is None else load_build_map(path, snapshot)
        context.odr = odr
    except InputError as reader_error:
        error = context.notes["reader_error"] = reader_error
    with frozen_heap():  # the map's millions of objects live through every rule: not scanned by each collection
        for rule in rules:
            if rule.id in AFTER_LOAD:
                found[rule.id] = _check(context, rule, strict)
            elif rule.needs != "xml":
                available[rule.id] = context.odr is not None
                if available[rule.id]:
                    found[rule.id] = _check(context, rule, strict)
    return _report(context, rules, found, available, strict, version), context.odr, error


def validate_map(odr, rules=None, strict: bool = False) -> ValidationReport:
    """Validate an already loaded OpenDriveMap (map rules only: structure rules need the raw document)."""
    context = ValidationContext(odr.source or "<map>", odr)
    return _run(context, select_rules(rules), strict, odr.header.revision)


def _run(context: ValidationContext, rules, strict: bool, version: str | None) -> ValidationReport:
    rules = list(rules)
    available = {rule.id: context.root is not None if rule.needs == "xml" else context.odr is not None
                 for rule in rules}
    found = {rule.id: _check(context, rule, strict) for rule in rules if available[rule.id]}
    return _report(context, rules, found, available, strict, version)


def _report(context: ValidationContext, rules, found: dict, available: dict, strict: bool,
            version: str | None) -> ValidationReport:
    """The report of the rules that ran, findings in catalogue order whatever order the rules ran in."""
    findings = [finding for rule in rules for finding in found.get(rule.id, ())]
    ran = [rule.id for rule in rules if available[rule.id]]
    skipped = [rule.id for rule in rules if not available[rule.id]]
    notes = {key: value for key, value in context.notes.items() if not key.startswith("_") and key != "reader_error"}
    return ValidationReport(context.name, tuple(findings), tuple(ran), strict, version, notes, tuple(skipped))


def _check(context: ValidationContext, rule, strict: bool) -> list:
    findings = []
    severity = ERROR if strict and rule.severity == WARNING else rule.severity
    try:
        for hit in rule.check(context, rule):
            findings.append(Finding(rule.id, severity, hit.road, hit.lane, hit.s, hit.line, hit.message))
    except MapkitError as error:
        # a rule that would sample an implausible road (or over the map's budget) reports why it could not
        # check, and the other rules still run: a validator's job is to list what is wrong
        findings.append(Finding(rule.id, ERROR, error.road, None, None, error.line,
                                f"not checked: {error.message}"))
    return findings
