"""ASAM's quality checker for OpenDRIVE (PyPI asam-qc-opendrive), in its own venv: it pins numpy < 2.

    >>> result = check("map.xodr", folder)     # {"issues": {checker: n}, "levels": {...}, "skipped": [...]}

It is a command-line program driven by a config file naming the ``InputFile`` and the checkers to run; its
result is an ``.xqar`` XML file. A checker whose preconditions fail (e.g. the schema check) is reported
``skipped``, so "no issues" only means something together with the list of skipped checkers.
"""

from __future__ import annotations

import subprocess
import time
from collections import Counter
from pathlib import Path

from .cache import peer_venv

REQUIREMENT = "asam-qc-opendrive"
_CHECKER_WORDS = """valid_xml_document root_tag_is_opendrive fileheader_is_present version_is_defined
valid_schema road_lane_level_true_one_side road_lane_access_no_mix_of_deny_or_allow
road_lane_link_lanes_across_lane_sections road_linkage_is_junction_needed road_lane_link_zero_width_at_start
road_lane_link_zero_width_at_end
road_lane_link_new_lane_appear junctions_connection_connect_road_no_incoming_road
junctions_connection_one_connection_element junctions_connection_one_link_to_incoming
junctions_connection_start_along_linkage junctions_connection_end_opposite_linkage
road_geometry_parampoly3_length_match road_lane_border_overlap_with_inner_lanes
road_geometry_parampoly3_arclength_range road_geometry_parampoly3_normalized_range
performance_avoid_redundant_info lane_smoothness_contact_point_no_horizontal_gaps"""
CHECKERS = _CHECKER_WORDS.split()
_XML_CHECKS = {
    "valid_xml_document",
    "root_tag_is_opendrive",
    "fileheader_is_present",
    "version_is_defined",
    "valid_schema",
}
LEVELS = {"1": "error", "2": "warning", "3": "info"}


def program(install: bool = False) -> Path:
    """The ``qc_opendrive`` command of the peer's venv (benchmarks/.peers/qc)."""
    return peer_venv("qc", REQUIREMENT, "bin/qc_opendrive", install)


def config_text(xodr: Path, result: Path) -> str:
    checkers = "\n".join(
        f'    <Checker checkerId="check_asam_xodr_{"xml_" if name in _XML_CHECKS else ""}{name}" '
        'maxLevel="1" minLevel="3"/>'
        for name in CHECKERS
    )
    return f"""<?xml version="1.0" encoding="UTF-8" standalone="no"?>
<Config>
  <Param name="InputFile" value="{xodr}"/>
  <CheckerBundle application="xodrBundle">
    <Param name="resultFile" value="{result}"/>
{checkers}
  </CheckerBundle>
</Config>
"""


def read_result(path: Path) -> dict:
    """Issues per checker (without the ``check_asam_xodr_`` prefix), per level, and the skipped checkers."""
    import re

    from lxml import etree

    root = etree.parse(str(path)).getroot()
    issues, levels, skipped, first, why = Counter(), Counter(), [], {}, Counter()
    for checker in root.iter("Checker"):
        name = checker.get("checkerId").replace("check_asam_xodr_", "")
        if checker.get("status") == "skipped":
            skipped.append(name)
            summary = checker.get("summary") or ""
            version = re.search(r"(?:definition setting|applicable version) ([^\s.]+(?:\.\d+)*)", summary)
            why[f"needs OpenDRIVE {version.group(1)}" if version else "preconditions failed"] += 1
        for issue in checker.iter("Issue"):
            issues[name] += 1
            levels[LEVELS.get(issue.get("level"), issue.get("level"))] += 1
            if name not in first:
                where = issue.find(".//FileLocation")
                place = issue.find("Locations")
                first[name] = (f"line {where.get('row')}: " if where is not None else "") + (
                    place.get("description") if place is not None else issue.get("description")
                )
    return {
        "skipped_why": dict(why),
        "issues": dict(sorted(issues.items())),
        "levels": dict(levels),
        "skipped": skipped,
        "total": sum(issues.values()),
        "first": first,
    }


def as_version(xodr: Path, folder: Path, minor: int) -> Path:
    """A copy of ``xodr`` in ``folder`` whose header says OpenDRIVE 1.``minor``: the checker applies a rule
    only to files of the versions it belongs to (most are from 1.7 on), so a 1.4 file (netconvert's) is
    checked by few of them."""
    import re

    text = xodr.read_text(encoding="utf-8")
    header = re.search(r"<header\b[^>]*>", text)
    if header is None:
        raise RuntimeError(f"{xodr}: no <header>")
    tag = re.sub(r'revMinor="\d+"', f'revMinor="{minor}"', header.group(0))
    copy = folder / f"{xodr.stem}.as-1.{minor}.xodr"
    copy.write_text(text[: header.start()] + tag + text[header.end():], encoding="utf-8")
    return copy


def check(xodr: Path | str, folder: Path, qc: Path | None = None, minor: int | None = None) -> dict:
    """Run every checker of CHECKERS on ``xodr`` (read as OpenDRIVE 1.``minor`` when given, see as_version);
    config and result are written into ``folder``."""
    xodr = Path(xodr).resolve()
    qc = qc or program()
    if minor is not None:
        xodr = as_version(xodr, folder, minor)
    result, config = folder / f"{xodr.stem}.xqar", folder / f"{xodr.stem}.qc.xml"
    config.write_text(config_text(xodr, result))
    start = time.perf_counter()
    done = subprocess.run(
        [str(qc), "-c", str(config)], capture_output=True, text=True, timeout=1800, cwd=folder, check=False
    )
    seconds = time.perf_counter() - start
    if done.returncode != 0 or not result.exists():
        return {"error": (done.stderr.strip().splitlines() or ["failed"])[-1][:200], "process": seconds}
    return {"process": seconds, **read_result(result)}
