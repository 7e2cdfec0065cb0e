"""CI accuracy regression: measure the real data and compare with tavf_mapkit/data/baselines/accuracy.json.

A metric worse than its baseline beyond the stated tolerance fails. Baselines change only through
``mapkit baseline refresh`` (never from a test).
"""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import shared_path

from tavf_mapkit.accuracy.baseline import BASELINE_FILE, MEASUREMENTS, load_baselines, regressions


@pytest.fixture(scope="module")
def real_inputs(jungfernstieg_build, tavf_dlr_build):
    return {"jungfernstieg_xodr": jungfernstieg_build / "jungfernstieg.xodr",
            "tavf_dlr_xodr": tavf_dlr_build / "tavf-dlr.xodr",
            "dlr_net": shared_path("hamburg", "tavf_dlr_sumo_net", "network.net.xml.gz"),
            "ride": shared_path("hamburg", "gnss_ride_b4", "thomas.json")}


def test_baseline_file_covers_every_measurement_with_tolerances():
    baselines = load_baselines(BASELINE_FILE)
    assert set(baselines["measurements"]) == set(MEASUREMENTS)
    for name, entry in baselines["measurements"].items():
        assert set(entry["metrics"]) == set(MEASUREMENTS[name].defaults), name
        for spec in entry["metrics"].values():
            assert spec["tolerance"] >= 0 and spec["better"] in ("lower", "higher", "equal")


def test_the_baselines_read_and_refreshed_are_the_checkouts_tracked_file():
    # package data (so a wheel has them), found through importlib.resources: in a development checkout that
    # must be the file git tracks, or `mapkit baseline refresh` would write where nobody commits
    repo = Path(__file__).resolve().parents[1]
    tracked = repo / "tavf_mapkit" / "data" / "baselines" / "accuracy.json"
    assert BASELINE_FILE.resolve() == tracked.resolve()
    assert BASELINE_FILE.is_file()


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(MEASUREMENTS))
def test_accuracy_not_worse_than_baseline(name, real_inputs):
    measured = MEASUREMENTS[name].run(real_inputs)
    assert regressions(name, measured, load_baselines(BASELINE_FILE)) == []


def test_regressions_respect_direction_and_tolerance():
    baselines = {"measurements": {"m": {"metrics": {
        "median_m": {"value": 2.0, "tolerance": 0.1, "better": "lower"},
        "share": {"value": 0.7, "tolerance": 0.01, "better": "higher"},
        "dx": {"value": 0.0, "tolerance": 0.05, "better": "equal"}}}}}
    assert regressions("m", {"median_m": 2.1, "share": 0.69, "dx": -0.05}, baselines) == []
    assert regressions("m", {"median_m": 1.0, "share": 0.99, "dx": 0.0}, baselines) == []   # better passes
    problems = regressions("m", {"median_m": 2.11, "share": 0.68, "dx": 0.06}, baselines)
    assert [p.split(":")[1].split("=")[0].strip() for p in problems] == ["median_m", "share", "dx"]
    assert regressions("other", {}, baselines) == ["other: no baseline (run `mapkit baseline refresh`)"]
