"""The validator's answer: findings, a summary, the JSON contract and the exit code."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

from tavf_mapkit.validate.finding import ERROR, INFO, WARNING, Finding

_RANK = {ERROR: 0, WARNING: 1, INFO: 2}


@dataclass(frozen=True)
class ValidationReport:
    file: str | None
    findings: tuple[Finding, ...]
    rules: tuple[str, ...]  # ids of the rules that ran
    strict: bool = False
    version: str | None = None
    notes: dict = field(default_factory=dict, compare=False)  # e.g. {"schema": {...}}
    skipped: tuple[str, ...] = ()  # rules selected but not run (e.g. map rules on an unreadable map)

    def count(self, severity: str) -> int:
        return sum(1 for finding in self.findings if finding.severity == severity)

    @property
    def errors(self) -> tuple[Finding, ...]:
        return tuple(f for f in self.findings if f.severity == ERROR)

    @property
    def exit_code(self) -> int:
        """0: no errors; 1: errors (in strict mode warnings are errors). Unreadable files never get a report."""
        return 1 if any(f.severity == ERROR for f in self.findings) else 0

    @property
    def summary(self) -> dict:
        by_rule = Counter(f.rule for f in self.findings)
        return {
            "errors": self.count(ERROR),
            "warnings": self.count(WARNING),
            "info": self.count(INFO),
            "by_rule": dict(sorted(by_rule.items())),
            "version": self.version,
            "rules_run": len(self.rules),
            "rules_skipped": list(self.skipped),
            "strict": self.strict,
            "schema": self.notes.get("schema"),
            "exit_code": self.exit_code,
        }

    def by_rule(self, rule_id: str) -> list[Finding]:
        return [f for f in self.findings if f.rule == rule_id]

    def to_dict(self) -> dict:
        return {"file": self.file, "findings": [f.to_dict() for f in self.findings], "summary": self.summary}

    def format_text(self, limit: int | None = 50, show_info: bool = True) -> str:
        shown = [f for f in self.findings if show_info or f.severity != INFO]
        shown.sort(key=lambda f: (_RANK[f.severity], f.rule, f.line or 0))
        lines = [f"{self.file}" + (f" (OpenDRIVE {self.version})" if self.version else "")]
        for finding in shown[:limit] if limit else shown:
            lines.append(f"  {finding}")
        if limit and len(shown) > limit:
            lines.append(f"  ... and {len(shown) - limit} more (--limit 0 or --json for all)")
        summary = self.summary
        counts = ", ".join(f"{rule} {n}" for rule, n in summary["by_rule"].items())
        lines.append(f"{summary['errors']} errors, {summary['warnings']} warnings, {summary['info']} notes "
                     f"from {summary['rules_run']} rules" + (f" ({counts})" if counts else ""))
        schema = summary["schema"]
        if schema and schema["status"] == "unavailable":
            lines.append(f"schema: no XSD for OpenDRIVE {schema['version']} at hand (see --schema-dir)")
        elif schema:
            lines.append(f"schema: {schema['status']} ({schema['path']})")
        if self.skipped:
            lines.append(f"not run (map could not be read): {len(self.skipped)} rules")
        return "\n".join(lines)
