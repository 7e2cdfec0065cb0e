"""The rule catalogue as Markdown, generated from the registry (docs/validation-rules.md holds a copy between
markers; a test keeps them equal). Regenerate with ``python -m tavf_mapkit.validate.catalogue docs/validation-rules.md``.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

from tavf_mapkit.validate.registry import FAMILIES, all_rules

BEGIN = "<!-- rules:begin (generated from tavf_mapkit/validate/registry.py; do not edit by hand) -->"
END = "<!-- rules:end -->"


def _cell(text: str) -> str:
    """Table-safe Markdown: element names as code (a bare <road> would be read as HTML), pipes escaped."""
    return re.sub(r"(<[^<>]+>)", r"`\1`", text).replace("|", "\\|").replace("\n", " ")


def render_catalogue() -> str:
    rules = all_rules()
    lines = []
    for family in FAMILIES:
        lines += [f"### {family}", "", "| id | severity | tolerance | what is checked | why it matters |",
                  "|---|---|---|---|---|"]
        for rule in rules.values():
            if rule.family == family:
                lines.append(f"| `{rule.id}` | {rule.severity} | {rule.tolerance_text} | {_cell(rule.summary)} | "
                             f"{_cell(rule.why)} |")
        lines.append("")
    return "\n".join(lines).rstrip() + "\n"


def replace_catalogue(document: str) -> str:
    """The document with the text between the markers replaced by the current catalogue."""
    start, end = document.index(BEGIN) + len(BEGIN), document.index(END)
    return document[:start] + "\n" + render_catalogue() + document[end:]


def catalogue_in(document: str) -> str:
    start, end = document.index(BEGIN) + len(BEGIN), document.index(END)
    return document[start:end].strip("\n") + "\n"


if __name__ == "__main__":
    path = Path(sys.argv[1] if len(sys.argv) > 1 else "docs/validation-rules.md")
    from tavf_mapkit.fileutil import write_text_atomic

    write_text_atomic(path, replace_catalogue(path.read_text()))
