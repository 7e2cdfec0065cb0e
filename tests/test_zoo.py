"""The map zoo as a standing test: a representative subset of ../shared/data/zoo through benchmarks/zoo.py.

One map per hard case the zoo was made for: a North-American grid (West Oakland), left-hand traffic and a
roundabout (Perth), a dense European centre (Berlin Neukoelln), a rural network of dead ends (Krautsand), and an OpenDRIVE
file with ``rule="LHT"`` as build input (esmini). Each is built, validated and driven for two seeds (200 s each here; the full
600 s runs are benchmarks/zoo.py's, in docs/zoo.md), the first seed twice; the runner's acceptance rules (build exit 0 within 2 GB, drives that end by themselves with no
reset, collision or off-road second, byte-identical repeat) must hold for every row.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import REPO, shared_path

SUBSET = ("US_west_oakland", "AU_perth_peanut_roundabout_LHT", "DE_berlin_neukoelln", "krautsand",
          "esmini_e6mini-lht_LHT")


@pytest.mark.slow
def test_zoo_subset_builds_validates_and_drives_cleanly(tmp_path: Path):
    shared_path("zoo", "MANIFEST.tsv")
    shared_path("osm_small", "krautsand.osm.gz")
    out = tmp_path / "zoo.json"
    run = subprocess.run(
        [sys.executable, str(REPO / "benchmarks" / "zoo.py"), "--only", ",".join(SUBSET), "--duration", "200",
         "--scratch", str(tmp_path / "scratch"), "--json", str(out)],
        capture_output=True, text=True, timeout=1500, check=False)
    assert out.exists(), run.stderr[-2000:]
    rows = {row["name"]: row for row in json.loads(out.read_text())}
    assert sorted(rows) == sorted(SUBSET)
    for name, row in rows.items():
        assert row["build_status"] == "ok", f"{name}: {row['build_reason']}"
        assert row["build_peak_mib"] <= 2048, name
        assert row["validation_errors"] is not None, name
        assert len(row["drives"]) == 2
        for drive in row["drives"]:
            assert drive["status"] == "ok", f"{name} seed {drive['seed']}: {drive['reason']}"
            assert (drive["resets"], drive["collisions"], drive["off_road_s"]) == (0, 0, 0.0), (name, drive)
            assert drive["distance_km"] > 0.5, (name, drive)
        assert row["deterministic"] is True, name
    assert run.returncode == 0, run.stdout[-3000:]
    assert "Traceback" not in run.stdout + run.stderr
    sides = {name: row["driving_side"] for name, row in rows.items()}
    assert sides["AU_perth_peanut_roundabout_LHT"] == "left"
    assert sides["esmini_e6mini-lht_LHT"] == "left"
    assert sides["US_west_oakland"] == "right"
