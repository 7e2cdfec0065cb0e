"""The check stage: validate, georeference round trip, compare and match-trace against pipeline references."""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest

from tavf_mapkit.pipeline.config import PipelineConfig
from tavf_mapkit.pipeline.context import BuildContext
from tavf_mapkit.pipeline.stages import get_stage


def _context(build_dir, tmp_path, check: dict) -> BuildContext:
    folder = tmp_path / "out"
    folder.mkdir()
    xodr = build_dir / f"{build_dir.name}.xodr"
    config = PipelineConfig(sections={"check": check})
    return BuildContext(name=build_dir.name, folder=folder, input_path=xodr, input_kind="osm", config=config,
                        artifacts={"xodr": xodr})


def _trace_on_lanes(build_dir, path):
    """A CSV trace along the first lanes of the map, 1.5 m to the side of their centre lines."""
    from tavf_mapkit.lanegraph import LaneGraph
    from tavf_mapkit.opendrive import load_opendrive

    odr = load_opendrive(build_dir / f"{build_dir.name}.xodr")
    graph = LaneGraph.from_opendrive(odr)
    key = max(graph.keys, key=graph.length)
    points, _ = graph.centerline(key, step=2.0)
    direction = np.gradient(points[:, :2], axis=0)
    normal = np.column_stack([-direction[:, 1], direction[:, 0]]) / np.linalg.norm(direction, axis=1)[:, None]
    beside = points[:, :2] + 1.5 * normal
    lon, lat = odr.georeference.local_to_wgs84(beside[:, 0], beside[:, 1])
    path.write_text("lat,lon\n" + "".join(f"{b:.9f},{a:.9f}\n" for a, b in zip(lon, lat)))
    return path


def test_check_stage_writes_reports_and_evaluates_thresholds(sample_build_dir, tmp_path):
    trace = _trace_on_lanes(sample_build_dir, tmp_path / "trace.csv")
    check = {"reference_network_path": sample_build_dir / "sample.net.xml", "gnss_trace_path": trace,
             "thresholds": {"reference_median_offset_m": 0.1, "reference_min_coverage": 0.9,
                            "gnss_median_distance_m": 0.5, "georeference_roundtrip_m": 0.01,
                            "no_such_threshold": 1},
             "validation": {"max_errors": 10**6}}  # this test is about the reference thresholds
    context = _context(sample_build_dir, tmp_path, check)
    output = get_stage("check").run(context)
    report = json.loads((context.folder / "report" / "check.json").read_text())
    checks = {c["key"]: c for c in report["checks"]}
    # the build against its own SUMO network: netconvert's OpenDRIVE lies on the SUMO lanes
    assert checks["reference_median_offset_m"]["passed"] is True
    assert checks["reference_min_coverage"]["passed"] is True
    # fixes 1.5 m beside a lane centre: the median distance is not below 0.5 m
    assert checks["gnss_median_distance_m"]["passed"] is False
    assert checks["gnss_median_distance_m"]["value"] == pytest.approx(1.5, abs=0.3)
    assert checks["georeference_roundtrip_m"]["passed"] is True
    assert checks["no_such_threshold"]["passed"] is None
    assert report["status"] == "fail" and output.facts["failed"] == ["gnss_median_distance_m"]
    for name in ("check.json", "validate.json", "compare.json", "compare.png", "match-trace.json",
                 "match-trace.png", "index.html"):
        assert (context.folder / "report" / name).is_file(), name
    # the file as the build names it, not the path in the staging folder it was read from
    validated = json.loads((context.folder / "report" / "validate.json").read_text())
    assert validated["file"] == report["file"] == context.artifacts["xodr"].name
    html = (context.folder / "report" / "index.html").read_text()
    assert html.count("<img alt=") == 2
    # self-contained: no link out in the markup (base64 data is removed first, it can spell "http" by chance;
    # the inline scripts and styles of the map are not markup -- tests/test_view_browser.py opens the page
    # from disk and fails on any request it makes)
    markup = re.sub(r"<script>.*?</script>|<style>.*?</style>", "", html, flags=re.S)
    text = re.sub(r"data:image/png;base64,[A-Za-z0-9+/=]+", "", markup).replace("http-equiv", "")
    assert "http" not in text and "src=\"/" not in text
    assert "window.MAPKIT_DATA = {" in html and "class='report-map'" in html
    assert set(output.files.values()) <= {str(p.relative_to(context.folder)) for p in context.folder.rglob("*")}


def test_check_stage_without_references_still_validates(sample_build_dir, tmp_path):
    context = _context(sample_build_dir, tmp_path, {})
    output = get_stage("check").run(context)
    report = json.loads((context.folder / "report" / "check.json").read_text())
    # the one check without references: validation errors, none allowed by default
    [check] = report["checks"]
    assert check["key"] == "validation.max_errors" and check["limit"] == 0
    assert check["value"] == output.facts["validate_errors"] == report["validate"]["errors"]
    assert report["status"] == ("pass" if check["value"] == 0 else "fail")
    assert "compare" not in report and "match" not in report
    assert report["georeference"]["roundtrip_m"] < 1e-6


def _checked(tmp_path, xodr, check: dict, facts: dict | None = None):
    """Run the check stage on one OpenDRIVE file; return (check.json, facts, index.html)."""
    folder = tmp_path / "out"
    folder.mkdir()
    context = BuildContext(name="net", folder=folder, input_path=xodr, input_kind="opendrive",
                           config=PipelineConfig(sections={"check": check}), artifacts={"xodr": xodr},
                           facts=facts or {})
    output = get_stage("check").run(context)
    report = json.loads((folder / "report" / "check.json").read_text())
    return report, output.facts, (folder / "report" / "index.html").read_text()


def _faulty_network(tmp_path):
    """The validator's clean test network with its second geometry 5 cm off and turned by 0.5 degrees, and
    road 1's right lane linked to a lane road 2 does not have: errors of two rules and warnings, independent
    of netconvert and of any repair."""
    from tests.validate_network import line, write_network

    geometry = line(0.0, 0.0, 0.0, 60.0) + line(60.0, 60.0, 0.05, 40.0, hdg=math.radians(0.5))
    return write_network(tmp_path, road1_geometry=geometry, road1_right_successor=-5)


def test_a_clean_file_passes_and_says_so(tmp_path):
    from tests.validate_network import write_network

    report, facts, html = _checked(tmp_path, write_network(tmp_path), {})
    assert report["validate"]["errors"] == 0 and report["status"] == "pass" and facts["failed"] == []
    assert "Check of net.xodr: PASS" in html and "FAIL" not in html


def test_validation_errors_fail_the_check_with_counts_per_rule(tmp_path):
    report, facts, html = _checked(tmp_path, _faulty_network(tmp_path), {})
    errors = report["validate"]["errors_by_rule"]
    assert errors["geometry.gap"] == 1 and errors["topology.lane-link-target"] == 1
    total = sum(errors.values())
    assert report["validate"]["errors"] == total >= 2
    assert report["status"] == "fail" and facts["failed"] == ["validation.max_errors"]
    assert facts["validate_errors_by_rule"] == errors
    assert facts["failed_checks"] == [{"key": "validation.max_errors", "what": "validation errors",
                                       "value": total, "limit": 0, "kind": "max"}]
    # the page: the verdict, never "pass" beside errors, and one row per rule with its count and first finding
    assert f"Check of net.xodr: FAIL</h1>\n<p>validation: {total} errors" in html
    assert "PASS" not in html and ">pass<" not in html
    row = re.search(r"<tr class='error'><td>geometry.gap</td><td>error</td><td>1</td><td></td>"
                    r"<td>counted</td>"
                    r"<td>([^<]*)</td></tr>", html)
    assert row and row.group(1).startswith("line ") and "road 1" in row.group(1)


def test_validation_limits_overall_per_rule_and_for_warnings(tmp_path):
    xodr = _faulty_network(tmp_path)
    runs = iter(range(100))

    def status(check: dict) -> tuple[str, list]:
        folder = tmp_path / f"run{next(runs)}"
        folder.mkdir()
        report, facts, _ = _checked(folder, xodr, check)
        return report["status"], facts["failed"]

    (tmp_path / "first").mkdir()
    first, _, _ = _checked(tmp_path / "first", xodr, {})
    errors, warnings = first["validate"]["errors"], first["validate"]["warnings"]
    assert first["status"] == "fail" and errors >= 2 and warnings >= 1  # geometry.kink among the warnings
    assert status({"validation": {"max_errors": errors}}) == ("pass", [])
    assert status({"validation": {"max_errors": errors - 1}}) == ("fail", ["validation.max_errors"])
    # a rule with its own limit counts there and no longer in max_errors
    others = errors - 1
    assert status({"validation": {"max_errors": others, "rules": {"geometry.gap": 1}}}) == ("pass", [])
    assert status({"validation": {"max_errors": others, "rules": {"geometry.gap": 0}}}) == \
        ("fail", ["validation.rules.geometry.gap"])
    assert status({"validation": {"max_errors": errors, "max_warnings": warnings}}) == ("pass", [])
    assert status({"validation": {"max_errors": errors, "max_warnings": warnings - 1}}) == \
        ("fail", ["validation.max_warnings"])
    # a warning rule with its own limit is judged there, even when warnings are not limited at all
    assert status({"validation": {"max_errors": errors, "rules": {"geometry.kink": 0}}}) == \
        ("fail", ["validation.rules.geometry.kink"])


def test_repairs_recorded_by_the_opendrive_stage_are_listed(tmp_path):
    from tests.validate_network import write_network

    repairs = {"geometry-length": 3, "contact-gap": {"count": 2, "links_dropped": 1}}
    facts = {"opendrive": {"repairs": repairs}}
    report, _, html = _checked(tmp_path, write_network(tmp_path), {}, facts)
    assert report["repairs"] == [{"repair": "geometry-length", "count": 3, "detail": None},
                                 {"repair": "contact-gap", "count": 2, "detail": {"links_dropped": 1}}]
    assert "<tr><td>geometry-length</td><td>3</td><td></td></tr>" in html
    assert "<tr><td>contact-gap</td><td>2</td><td>links_dropped: 1</td></tr>" in html
    folder = tmp_path / "list"
    folder.mkdir()
    listed = {"opendrive": {"repairs": [{"kind": "controller-id", "count": 4, "roads": ["7", "9"]}]}}
    report, _, html = _checked(folder, write_network(folder), {}, listed)
    assert report["repairs"] == [{"repair": "controller-id", "count": 4, "detail": {"roads": ["7", "9"]}}]
    assert "<tr><td>controller-id</td><td>4</td><td>roads: 7, 9</td></tr>" in html
    for facts, says in (({"opendrive": {"repairs": {}}}, "None were needed."),
                        ({}, "None recorded by the opendrive stage.")):
        folder = tmp_path / f"facts{len(facts)}"
        folder.mkdir()
        html = _checked(folder, write_network(folder), {}, facts)[2]
        assert f"<h2>Repairs of the OpenDRIVE</h2>\n<p>{says}</p>" in html


def test_unreadable_reference_is_reported_not_fatal(sample_build_dir, tmp_path):
    broken = tmp_path / "broken.net.xml"
    broken.write_text("<net><edge")
    empty = tmp_path / "empty.csv"
    empty.write_text("lat,lon\n")
    context = _context(sample_build_dir, tmp_path, {"reference_network_path": broken, "gnss_trace_path": empty,
                                                    "thresholds": {"gnss_median_distance_m": 8.0}})
    get_stage("check").run(context)
    report = json.loads((context.folder / "report" / "check.json").read_text())
    assert "broken.net.xml" in report["compare"]["error"]
    assert report["match"]["error"].endswith("empty.csv: the trace has no fixes (empty trace)")
    assert {c["key"]: c["passed"] for c in report["checks"]}["gnss_median_distance_m"] is None


def test_the_build_prints_the_verdict_and_still_succeeds(sample_build_dir):
    """A build whose OpenDRIVE fails the check is still a build (exit 0, the fixture asserts it); its summary
    says so in one line, with the errors by rule."""
    from tavf_mapkit.pipeline.summary import render_summary

    manifest = json.loads((sample_build_dir / "manifest.json").read_text())
    facts = {record["name"]: record["facts"] for record in manifest["stages"]}["check"]
    lines = render_summary(manifest, sample_build_dir).splitlines()
    [line] = [line for line in lines if line.startswith("check")]
    errors = facts["validate_errors"]
    assert line.startswith(f"check   {facts['status'].upper()}: {errors} validation errors")
    assert line.endswith(f", {facts['validate_warnings']} warnings" + (
        f"; over the limit: validation errors {errors} > 0 (report/index.html)" if errors else
        " (report/index.html)"))
    assert (facts["status"] == "fail") == (errors > 0)
    for rule, count in sorted(facts["validate_errors_by_rule"].items(), key=lambda item: -item[1])[:3]:
        assert f"{rule} {count}" in line


def test_the_report_map_samples_a_big_map_more_coarsely(sample_build_dir, monkeypatch):
    """The report's map keeps the view's 1 m on a district and spreads a fixed number of samples over a region's
    lanes (its memory is bounded by REPORT_MAP_SAMPLES, not by the map)."""
    import numpy as np

    from tavf_mapkit.opendrive import load_opendrive
    from tavf_mapkit.pipeline.builtin import check

    odr = load_opendrive(next(sample_build_dir.glob("*.xodr")))
    arrays = odr.arrays
    lane_length = float(np.sum((arrays.section_end - arrays.section_s0)[arrays.lane_section]))
    assert lane_length > 100 and check.report_map_step(odr) == 1.0
    monkeypatch.setattr(check, "REPORT_MAP_SAMPLES", 50)
    assert check.report_map_step(odr) == lane_length / 50
