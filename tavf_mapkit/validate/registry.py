"""The rule catalogue: every rule's id, family, severity, tolerance and why it matters, and its check.

Checks read their tolerance from here (``rule.tolerance``), so code, ``docs/validation-rules.md`` (generated from
this registry, see catalogue.py) and ``--rules`` never disagree.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass

from tavf_mapkit.validate.finding import SEVERITIES, Hit

FAMILIES = ("structure", "geometry", "topology", "georeference")


@dataclass(frozen=True)
class Rule:
    id: str
    severity: str
    summary: str  # what is checked, one line
    why: str  # why it matters
    check: Callable[..., Iterable[Hit]]
    tolerance: float | None = None
    unit: str = ""
    needs: str = "map"  # "map": the loaded OpenDriveMap; "xml": the raw document (line numbers, order, names)

    @property
    def family(self) -> str:
        return self.id.split(".", 1)[0]

    @property
    def tolerance_text(self) -> str:
        if self.tolerance is None:
            return "-"
        return f"{self.tolerance:g} {self.unit}".strip()


RULES: dict[str, Rule] = {}


def rule(rule_id: str, severity: str, summary: str, why: str, tolerance: float | None = None, unit: str = "",
         needs: str = "map"):
    """Register ``check(ctx, rule) -> iterable of Hit`` under ``rule_id`` (``family.name``)."""
    if severity not in SEVERITIES:
        raise ValueError(f"unknown severity {severity!r}")
    if rule_id.split(".", 1)[0] not in FAMILIES:
        raise ValueError(f"rule {rule_id!r} is in no known family")

    def register(check):
        if rule_id in RULES:
            raise ValueError(f"rule {rule_id!r} registered twice")
        RULES[rule_id] = Rule(rule_id, severity, summary, why, check, tolerance, unit, needs)
        return check

    return register


def all_rules() -> dict[str, Rule]:
    """Every rule, in catalogue order (family, then registration order)."""
    from tavf_mapkit.validate import geometry, georeference, structure, topology  # noqa: F401  (registers)
    # rules of ASAM's quality checker that the families above did not have; their rules follow in the catalogue
    from tavf_mapkit.validate import junctions, lanes, redundancy  # noqa: F401

    return {r.id: r for family in FAMILIES for r in RULES.values() if r.family == family}


def select_rules(spec: str | Iterable[str] | None) -> list[Rule]:
    """Rules named by ids or family names (``"geometry,topology.contact-gap"``); all when None or empty.

    An unknown name raises ValueError listing what exists, so a typo never silently disables a check.
    """
    rules = all_rules()
    if spec is None:
        return list(rules.values())
    names = [n.strip() for n in (spec.split(",") if isinstance(spec, str) else spec) if n.strip()]
    if not names:
        return list(rules.values())
    chosen: dict[str, Rule] = {}
    for name in names:
        if name in rules:
            chosen[name] = rules[name]
        elif name in FAMILIES:
            chosen.update({k: r for k, r in rules.items() if r.family == name})
        else:
            raise ValueError(f"unknown rule {name!r}; families: {', '.join(FAMILIES)}; "
                             f"rules: {', '.join(rules)}")
    return [r for r in rules.values() if r.id in chosen]
