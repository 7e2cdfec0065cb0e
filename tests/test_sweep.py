"""twin sweep: seeded drives through a real Dask cluster on loopback give, seed for seed, the metrics of running
``twin drive`` one by one; a run past its deadline is killed and counted; bad options are one line."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import shared_path
from dask_cluster import loopback_cluster

MAPKIT = str(Path(sys.executable).parent / "mapkit")
TWIN = str(Path(sys.executable).parent / "twin")
PERTH = ("zoo", "osm", "AU_perth_peanut_roundabout_LHT.osm.gz")
DURATION = "15"
WALL_CLOCK = ("wall_seconds", "real_time_factor", "setup_seconds")  # how fast the machine was, not the drive


@pytest.fixture(scope="module")
def perth(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("build") / "perth"
    subprocess.run([MAPKIT, "build", str(shared_path(*PERTH)), "-o", str(out), "-q"], check=True,
                   capture_output=True, timeout=600)
    return out


def drive_metrics(build: Path, seed: int, out: Path) -> dict:
    """``twin drive`` of one seed on its own, with the options a sweep gives every run."""
    subprocess.run([TWIN, "drive", "--map", str(build), "--random", "--duration", DURATION, "--seed", str(seed),
                    "--no-plot", "--no-record", "-o", str(out)], check=True, capture_output=True, timeout=600)
    return json.loads((out / "metrics.json").read_text())


def without_wall_clock(metrics: dict) -> dict:
    return {key: value for key, value in metrics.items() if key not in WALL_CLOCK}


@pytest.mark.parametrize("seeds", [
    pytest.param("0-2", id="3-seeds"),
    pytest.param("0-7", id="8-seeds", marks=pytest.mark.slow),
])
def test_sweep_on_loopback_cluster_matches_one_by_one(perth, tmp_path, seeds):
    pytest.importorskip("distributed")
    first, last = (int(v) for v in seeds.split("-"))
    out = tmp_path / "sweep"
    with loopback_cluster(tmp_path / "cluster", workers=2) as cluster:
        done = subprocess.run([TWIN, "sweep", "--map", str(perth), "--seeds", seeds, "--duration", DURATION,
                               "--scheduler", cluster.address, "-o", str(out), "-q"], capture_output=True,
                              text=True, timeout=900, check=False)
    assert done.returncode == 0, done.stderr
    rows = list(csv.DictReader((out / "sweep.csv").open()))
    assert [int(row["seed"]) for row in rows] == list(range(first, last + 1))
    report = json.loads((out / "sweep.json").read_text())
    assert report["summary"]["runs"] == report["summary"]["ok"] == last - first + 1
    for row in rows:
        seed = int(row["seed"])
        alone = drive_metrics(perth, seed, tmp_path / f"alone-{seed}")
        swept = json.loads((out / "runs" / f"seed-{seed}" / "metrics.json").read_text())
        assert without_wall_clock(swept) == without_wall_clock(alone), f"seed {seed}"
        assert row["status"] == "ok" and int(row["collisions"]) == alone["collisions"]
        assert int(row["resets"]) == alone["resets"] and float(row["off_road_s"]) == alone["off_road_seconds"]
        assert float(row["distance_m"]) == alone["distance_m"]
    # the seeds drove different routes: the comparison is not of one drive with itself
    assert len({row["distance_m"] for row in rows}) > 1


def test_run_past_its_deadline_is_killed_and_counted(perth, tmp_path):
    out = tmp_path / "sweep"
    done = subprocess.run([TWIN, "sweep", "--map", str(perth), "--seeds", "4", "--duration", "600",
                           "--timeout", "1", "-o", str(out), "-q"], capture_output=True, text=True, timeout=120,
                          check=False)
    assert done.returncode == 1
    assert done.stderr.strip().splitlines()[-1] == f"Error: 1 of 1 runs did not finish (see {out / 'sweep.csv'})"
    (row,) = csv.DictReader((out / "sweep.csv").open())
    assert row["seed"] == "4" and row["status"] == "timeout" and row["error"] == "no result within 1 s (killed)"
    report = json.loads((out / "sweep.json").read_text())
    assert report["summary"]["timed_out"] == 1
    assert report["summary"]["worst"] == [{"seed": 4, "why": "seed 4: timeout (no result within 1 s (killed))"}]


@pytest.mark.parametrize("args, message", [
    (["--seeds", "5-2"], "Error: --seeds '5-2': range 5-2 runs backwards"),
    (["--seeds", "a"], "Error: --seeds 'a': expected seeds such as 0-199 or 1,5,9-12"),
    (["--seeds", "1", "--workers", "2", "--scheduler", "tcp://127.0.0.1:1"],
     "Error: --workers and --scheduler exclude each other (a scheduler brings its own workers)"),
])
def test_bad_options_are_one_line(perth, tmp_path, args, message):
    done = subprocess.run([TWIN, "sweep", "--map", str(perth), *args, "-o", str(tmp_path / "s")],
                          capture_output=True, text=True, timeout=60, check=False)
    assert done.returncode == 2
    assert done.stderr.strip() == message
    assert not (tmp_path / "s").exists()


def test_not_a_build_is_one_line(tmp_path):
    done = subprocess.run([TWIN, "sweep", "--map", str(tmp_path), "--seeds", "0", "-o", str(tmp_path / "s")],
                          capture_output=True, text=True, timeout=60, check=False)
    assert done.returncode == 2
    assert done.stderr.strip() == (f"Error: {tmp_path}: not a build folder (no manifest.json; make one with "
                                   "`mapkit build`)")


@pytest.mark.parametrize("verbosity, chatty", [([], False), (["-v"], True)])
def test_a_local_cluster_logs_only_at_the_commands_verbosity(perth, tmp_path, verbosity, chatty):
    """Dask gives its loggers their own handler at INFO: the local scheduler's start and stop were ~35 lines on
    stderr of every `twin sweep --workers N`. Without -v nothing of them shows; `twin -v` shows them."""
    pytest.importorskip("distributed")
    done = subprocess.run([TWIN, *verbosity, "sweep", "--map", str(perth), "--seeds", "0", "--duration", "5",
                           "--workers", "2", "-o", str(tmp_path / "s"), "-q"], capture_output=True, text=True,
                          timeout=600, check=False)
    assert done.returncode == 0, done.stderr
    assert ("INFO distributed.scheduler" in done.stderr) is chatty, done.stderr
    if not chatty:
        assert done.stderr == ""


@pytest.mark.skipif(not hasattr(os, "sched_getscheduler"), reason="scheduling policies are Linux's")
def test_runs_are_started_as_batch_work_and_the_caller_keeps_its_policy():
    """A sweep's drives run under SCHED_BATCH (their steps never preempt a UDM request when they wake); the
    thread that starts them goes back to its own policy."""
    from twin.sweep.runs import batch_policy

    before = os.sched_getscheduler(0)
    ask = [sys.executable, "-c", "import os; print(os.sched_getscheduler(0))"]
    with batch_policy():
        inside = subprocess.run(ask, capture_output=True, text=True, check=True, timeout=60).stdout.strip()
    outside = subprocess.run(ask, capture_output=True, text=True, check=True, timeout=60).stdout.strip()
    assert int(inside) == os.SCHED_BATCH
    assert os.sched_getscheduler(0) == before == int(outside)
