"""Benchmark `mapkit build`: full build and rebuild of the sample and both real Hamburg inputs.

    $ .venv/bin/python benchmarks/bench_build.py                # 3 runs per case, median wall time
    $ .venv/bin/python benchmarks/bench_build.py --repeat 5 --keep benchmarks/results/build

Prints per-stage wall time and peak memory (from each build's manifest.json), the whole command's wall time
and peak RSS (resource.getrusage of the child processes, measured in a fresh process per run so the maximum
belongs to that run), the rebuild time of unchanged input, and for comparison ("peer") the same netconvert
commands run alone, so the pipeline's own overhead is visible. Targets: full build of Jungfernstieg <= 10 s,
TAVF <= 20 s, rebuild < 2 s; the ratio column is figure / target (below 1 is within target).

The manifest's peaks are maxima of the whole build so far, so a stage's own peak hides under an earlier one's.
``--stages-of INPUT`` measures each stage alone instead: the build is run once per stage, each time in a fresh
process with one stage more (a pipeline file of the first k stages, the stages before reused from the folder),
so that process's peak RSS is that stage's (issue 13's limit: every stage <= 2 GB):

    $ .venv/bin/python benchmarks/bench_build.py --stages-of ../shared/data/zoo/osm/SI_maribor.osm.gz \
          --keep /tmp/bench-maribor
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("TAVF_SHARED_DATA", REPO.parent / "shared" / "data"))
MAPKIT = Path(sys.executable).parent / "mapkit"
DEFAULT_STAGES = ("extract", "netconvert", "opendrive", "mesh", "collision", "check", "report")

CASES = [  # name, input, extra options, full-build target (s)
    ("sample", REPO / "sample_data" / "tavf_synthetic.osm", [], None),
    ("jungfernstieg", SHARED / "hamburg" / "jungfernstieg_osm" / "jungfernstieg_2023-03-10.osm", [], 10.0),
    ("tavf-net", SHARED / "hamburg" / "tavf_dlr_sumo_net" / "network.net.xml.gz", [], 20.0),
]
REBUILD_TARGET = 2.0


def measure(command: list[str], cwd: Path | None = None) -> dict:
    """Run ``command`` in a fresh Python process that reports wall time and its children's peak RSS."""
    probe = ("import json, resource, subprocess, sys, time\n"
             "t = time.perf_counter()\n"
             "run = subprocess.run(sys.argv[1:], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)\n"
             "code = run.returncode\n"
             "wall = time.perf_counter() - t\n"
             "rss = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss\n"
             "print(json.dumps({'code': code, 'wall': wall, 'peak_rss_mib': rss / 1024}))\n")
    completed = subprocess.run([sys.executable, "-c", probe, *command], capture_output=True, text=True,
                               cwd=cwd, check=False)
    if completed.returncode != 0:
        raise SystemExit(f"measuring {command} failed: {completed.stderr}")
    result = json.loads(completed.stdout)
    if result["code"] != 0:
        raise SystemExit(f"{shlex.join(command)} exited with {result['code']}")
    return result


def netconvert_alone(folder: Path, manifest: dict, scratch: Path) -> dict:
    """The netconvert commands the build ran, run alone on a copy of the build's source (the 'peer')."""
    from tavf_mapkit.netconvert import find_netconvert

    record = next(r for r in manifest["stages"] if r["name"] == "netconvert")
    work = scratch / "netconvert-alone"
    shutil.rmtree(work, ignore_errors=True)
    shutil.copytree(folder / "source", work / "source")
    (work / "logs" / "netconvert-plain").mkdir(parents=True)
    script = "; ".join(shlex.join([str(find_netconvert()), *shlex.split(command)[1:]])
                       for command in record["facts"]["commands"])
    return measure(["sh", "-c", script], cwd=work)


def run_case(name: str, source: Path, options: list[str], repeat: int, scratch: Path) -> dict:
    folder = scratch / name
    builds, rebuilds, manifests = [], [], []
    for _ in range(repeat):
        command = [str(MAPKIT), "build", str(source), "-o", str(folder), "-q", *options]
        builds.append(measure([*command, "--force"]))
        manifests.append(json.loads((folder / "manifest.json").read_text()))
        rebuilds.append(measure(command))
        statuses = {r["status"] for r in json.loads((folder / "manifest.json").read_text())["stages"]}
        assert statuses <= {"unchanged", "unavailable"}, f"rebuild of {name} reran a stage: {statuses}"
    stages = {}
    for record in manifests[0]["stages"]:
        if record["status"] != "ran":
            continue
        seconds = [next(r for r in m["stages"] if r["name"] == record["name"])["seconds"] for m in manifests]
        stages[record["name"]] = {"seconds": statistics.median(seconds),
                                  "peak_rss_mib": record["peak_rss_mib"]}
    peers = [netconvert_alone(folder, manifests[0], scratch) for _ in range(repeat)]
    return {
        "build_s": statistics.median(b["wall"] for b in builds),
        "build_peak_rss_mib": max(b["peak_rss_mib"] for b in builds),
        "rebuild_s": statistics.median(r["wall"] for r in rebuilds),
        "rebuild_peak_rss_mib": max(r["peak_rss_mib"] for r in rebuilds),
        "netconvert_alone_s": statistics.median(p["wall"] for p in peers),
        "netconvert_alone_peak_rss_mib": max(p["peak_rss_mib"] for p in peers),
        "stages": stages,
    }


def stage_by_stage(source: Path, stages: list[str], scratch: Path, options: list[str]) -> list[dict]:
    """Each stage's wall time and peak RSS, measured alone: build with the first k stages in a fresh process
    for k = 1..len(stages), the stages before reused from the folder (a stage that ran again is reported)."""
    folder = scratch / "build"
    rows = []
    for k, stage in enumerate(stages, 1):
        pipeline = scratch / f"stages-{k}.toml"
        pipeline.write_text("[pipeline]\nstages = [" + ", ".join(json.dumps(name) for name in stages[:k])
                            + "]\n", encoding="utf-8")
        figures = measure([str(MAPKIT), "build", str(source), "--pipeline", str(pipeline), "-o", str(folder), "-q",
                           *options])
        records = json.loads((folder / "manifest.json").read_text())["stages"]
        ran = [r for r in records if r["status"] == "ran"]
        mine = next((r for r in ran if r["name"] == stage), None)
        before = max((r["peak_rss_mib"]["mapkit"] for r in ran if r is not mine and records.index(r)
                      < records.index(mine)), default=0.0) if mine else 0.0
        # the manifest's peaks are the process's maxima so far: the stage's own when it rose above the stages
        # that ran before it in this process (a stage whose inputs changed runs again), else at most
        # the figure before
        own = None if mine is None else mine["peak_rss_mib"]["mapkit"]
        rows.append({"stage": stage, "wall_s": figures["wall"], "peak_rss_mib": figures["peak_rss_mib"],
                     "stage_peak_rss_mib": own, "stage_peak_is_bound": own is not None and own <= before,
                     "stage_s": None if mine is None else mine["seconds"],
                     "also_ran": [r["name"] for r in ran if r is not mine]})
    return rows


def print_stage_by_stage(source: Path, rows: list[dict]) -> None:
    print(f"mapkit build {source.name}, one stage per fresh process ({sys.platform}, {os.cpu_count()} CPUs)\n")
    print(f"{'stage':<11} {'stage s':>9} {'stage peak MiB':>15} {'process s':>10} {'process peak MiB':>17}  note")
    for row in rows:
        note = f"also ran: {', '.join(row['also_ran'])}" if row["also_ran"] else ""
        stage_s = "-" if row["stage_s"] is None else f"{row['stage_s']:.1f}"
        own = row["stage_peak_rss_mib"]
        own = "-" if own is None else ("<= " if row["stage_peak_is_bound"] else "") + f"{own:.1f}"
        print(f"{row['stage']:<11} {stage_s:>9} {own:>15} {row['wall_s']:10.1f} {row['peak_rss_mib']:17.1f}  {note}")
    print(f"\nbuild peak (largest process): {max(row['peak_rss_mib'] for row in rows):.1f} MiB"
          " (the process peak includes the subprocesses, e.g. netconvert)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--keep", type=Path, default=None, help="keep the build folders here")
    parser.add_argument("--json", action="store_true", help="print the figures as JSON")
    parser.add_argument("--stages-of", type=Path, default=None, metavar="INPUT",
                        help="measure each stage's peak RSS alone on this input (one fresh process per stage)")
    parser.add_argument("--stages", default=",".join(DEFAULT_STAGES),
                        help="with --stages-of: the stages, comma-separated (default: %(default)s)")
    parser.add_argument("--build-option", action="append", default=[],
                        help="with --stages-of: an extra option for mapkit build (repeatable)")
    arguments = parser.parse_args()
    if arguments.stages_of is not None:
        scratch = arguments.keep or Path(tempfile.mkdtemp(prefix="bench-stages-"))
        scratch.mkdir(parents=True, exist_ok=True)
        try:
            rows = stage_by_stage(arguments.stages_of, arguments.stages.split(","), scratch, arguments.build_option)
        finally:
            if not arguments.keep:
                shutil.rmtree(scratch, ignore_errors=True)
        if arguments.json:
            print(json.dumps(rows, indent=2))
        else:
            print_stage_by_stage(arguments.stages_of, rows)
        return
    if not SHARED.is_dir():
        raise SystemExit(f"shared data folder {SHARED} not present")
    if arguments.keep:
        arguments.keep.mkdir(parents=True, exist_ok=True)
    scratch = arguments.keep or Path(tempfile.mkdtemp(prefix="bench-build-"))
    try:
        results = {name: run_case(name, source, options, arguments.repeat, scratch)
                   for name, source, options, _ in CASES}
    finally:
        if not arguments.keep:
            shutil.rmtree(scratch, ignore_errors=True)
    if arguments.json:
        print(json.dumps(results, indent=2))
        return

    print(f"mapkit build, median of {arguments.repeat} runs ({sys.platform}, {os.cpu_count()} CPUs)\n")
    print(f"{'case':<14} {'stage':<11} {'wall s':>8} {'peak RSS MiB (mapkit / subprocesses)':>38}")
    for name, result in results.items():
        for stage, figures in result["stages"].items():
            rss = figures["peak_rss_mib"]
            print(f"{name:<14} {stage:<11} {figures['seconds']:8.3f} "
                  f"{rss['mapkit']:>20.1f} / {rss['subprocesses']:.1f}")
    print()
    print(f"{'case':<14} {'measure':<26} {'ours s':>8} {'peer s':>8} {'ours/peer':>9} {'target s':>9} "
          f"{'ours/target':>11} {'peak MiB':>9}")
    for name, _, _, target in CASES:
        result = results[name]
        peer = result["netconvert_alone_s"]
        rows = [("full build (--force)", result["build_s"], peer, target, result["build_peak_rss_mib"]),
                ("rebuild (unchanged)", result["rebuild_s"], None, REBUILD_TARGET,
                 result["rebuild_peak_rss_mib"])]
        for label, ours, peer_s, goal, rss in rows:
            peer_text = f"{peer_s:8.3f} {ours / peer_s:9.2f}" if peer_s else f"{'-':>8} {'-':>9}"
            goal_text = f"{goal:9.1f} {ours / goal:11.3f}" if goal else f"{'-':>9} {'-':>11}"
            print(f"{name:<14} {label:<26} {ours:8.3f} {peer_text} {goal_text} {rss:9.1f}")
    print("\npeer = the same netconvert commands run alone (no extract, hashing, report, manifest, swap)")


if __name__ == "__main__":
    main()
