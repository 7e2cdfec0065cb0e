"""``mapkit validate``: what is wrong in an OpenDRIVE file, and where.

    >>> from tavf_mapkit.validate import validate_file
    >>> report = validate_file("map.xodr")
    >>> report.exit_code, report.summary["errors"]
    >>> [f for f in report.findings if f.rule == "geometry.gap"]

One module per rule family (structure, geometry, topology, georeference); every rule is registered with id,
severity, tolerance and why it matters (registry.py), which is also what docs/validation-rules.md shows.
"""

from tavf_mapkit.validate.finding import ERROR, INFO, WARNING, Finding
from tavf_mapkit.validate.registry import Rule, all_rules, select_rules
from tavf_mapkit.validate.report import ValidationReport
from tavf_mapkit.validate.runner import validate_file, validate_map

__all__ = ["ERROR", "INFO", "WARNING", "Finding", "Rule", "ValidationReport", "all_rules", "select_rules",
           "validate_file", "validate_map"]
