"""The check stage: validate, georeference round trip, compare and match-trace against pipeline references."""

from __future__ import annotations

import json
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
                            "no_such_threshold": 1}}
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
    html = (context.folder / "report" / "index.html").read_text()
    assert html.count("data:image/png;base64,") == 2
    # self-contained: no link out (base64 data is removed first, it can spell "http" by chance)
    text = re.sub(r"data:image/png;base64,[A-Za-z0-9+/=]+", "", html).replace("http-equiv", "")
    assert "http" not in text and "src=\"/" not in text
    assert set(output.files.values()) <= {str(p.relative_to(context.folder)) for p in context.folder.rglob("*")}


def test_check_stage_without_references_still_validates(sample_build_dir, tmp_path):
    context = _context(sample_build_dir, tmp_path, {})
    output = get_stage("check").run(context)
    report = json.loads((context.folder / "report" / "check.json").read_text())
    assert report["checks"] == [] and report["status"] == "pass"
    assert "compare" not in report and "match" not in report
    assert output.facts["validate_errors"] is not None
    assert report["georeference"]["roundtrip_m"] < 1e-6


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
    assert report["checks"][0]["passed"] is None
