"""``twin drive --map`` at region scale: start-up (to the first simulated step) and real-time factor, GNSS only.

    $ .venv/bin/python benchmarks/bench_twin_start.py                              # sample + zoo Maribor, if built
    $ .venv/bin/python benchmarks/bench_twin_start.py --zoo /tmp/zoo-scratch       # zoo.py --scratch folder
    $ .venv/bin/python benchmarks/bench_twin_start.py BUILD [BUILD ...] --duration 600 --seed 0
    $ .venv/bin/python benchmarks/bench_twin_start.py BUILD --no-peers --against /tmp/old-checkout  # before/after

Per build, in the same run:
- ``twin drive --map BUILD --random --duration 600 --seed 0`` in a process of its own, as ``bench_twin.py``
  runs it (the Session without hooks: no MCAP recording, no plot): the start-up is the imports plus the
  metrics' ``setup_seconds`` (map, lane graph, routes, world: from the Session's start to its first step),
  i.e. process start to first step; the real-time factor is the metrics' (simulated over wall seconds of
  the loop). Targets (issue 15): start-up
  <= 30 s and >= 50x real time on a region.
- loading the same OpenDRIVE with our reader alone and with the C++ evaluator (../shared/tools/libopendrive
  through ``benchmarks/peers``, parse + one sample per lane), the floor a start-up could reach.

Default builds: the quickstart sample (built into a temporary folder) and the zoo build of Maribor (31,667
roads, a 407 MB OpenDRIVE) when ``--zoo`` (or $MAPKIT_ZOO) points at a ``zoo.py --scratch`` folder that has
it. The machine is shared: compare figures within one run. ``--against CHECKOUT`` also drives every build with
the code of another checkout of the repository (``PYTHONPATH=CHECKOUT``, e.g. a ``git worktree`` of an earlier
commit), alternating with this one ``--repeat`` times, each figure the median: before and after in one run.
This code drives twice per attempt from an empty cache of route plans (``twin.planning.route_cache``): "plan
computed" is a map's first drive, "plan kept" every later one on the same map and code.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
sys.path.insert(0, str(HERE))
from bench_region import cpp_load, our_load  # noqa: E402  (the load figures, one place)

BIN = Path(sys.executable).parent
START_TARGET_S = 30.0
RTF_TARGET = 50.0

def drive(build: Path, out: Path, duration: float, seed: int, code: Path | None = None,
          cache: Path | None = None) -> dict:
    """One ``twin drive`` in its own process; start-up = process start to first step. ``code``: a checkout whose
    ``twin`` and ``tavf_mapkit`` the process imports instead of this one's; ``cache``: the folder of kept route
    plans (``MAPKIT_CACHE``)."""
    script = (
        "import time\nt0 = time.perf_counter()\n"
        "import json, sys\nfrom twin.session.config import DriveConfig\nfrom twin.session.loop import Session\n"
        "t1 = time.perf_counter()\n"
        "config = DriveConfig(map=sys.argv[1], out=sys.argv[2], random=True, duration=float(sys.argv[3]),"
        " seed=int(sys.argv[4]), plot=False)\n"
        "metrics = Session(config, []).run()\n"
        "import twin\nprint(json.dumps({'imports_s': t1 - t0, 'code': twin.__file__, **metrics}))\n"
    )
    env = dict(os.environ)
    if cache is not None:
        env["MAPKIT_CACHE"] = str(cache)
    if code is not None:
        env["PYTHONPATH"] = os.pathsep.join([str(code), *filter(None, [env.get("PYTHONPATH")])])
    started = time.perf_counter()
    # run from the scratch folder: ``-c`` puts the working directory first on sys.path, before PYTHONPATH
    done = subprocess.run([sys.executable, "-c", script, str(build.resolve()), str(out.resolve()), str(duration),
                           str(seed)], capture_output=True, text=True, check=False, env=env, cwd=out.parent)
    wall = time.perf_counter() - started
    if done.returncode != 0:
        reason = (done.stderr.strip().splitlines() or ["no output"])[-1]
        raise SystemExit(f"twin drive on {build} failed: {reason}")
    metrics = json.loads(done.stdout.strip().splitlines()[-1])
    metrics["command_s"] = wall
    metrics["start_s"] = metrics["imports_s"] + metrics["setup_seconds"]
    return metrics


def _median_run(runs: list[dict]) -> dict:
    """The run of median start-up (its own real-time factor, too, replaced by the median of the runs')."""
    ordered = sorted(runs, key=lambda run: run["start_s"])
    median = dict(ordered[(len(ordered) - 1) // 2])
    rtfs = sorted(run["real_time_factor"] for run in runs)
    median["real_time_factor"] = rtfs[(len(rtfs) - 1) // 2]
    return median


def default_builds(zoo: Path | None, scratch: Path) -> list[Path]:
    sample = scratch / "sample"
    subprocess.run([str(BIN / "mapkit"), "build", str(REPO / "sample_data" / "tavf_synthetic.osm"), "-o",
                    str(sample), "-q"], check=True)
    builds = [sample]
    maribor = zoo / "SI_maribor" / "build" if zoo else None
    if maribor is not None and (maribor / "manifest.json").is_file():
        builds.append(maribor)
    else:
        print("(no zoo build of Maribor: pass --zoo DIR of a `zoo.py --scratch DIR` run, or a BUILD)",
              file=sys.stderr)
    return builds


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("builds", nargs="*", type=Path, help="build folders (default: sample + zoo Maribor)")
    parser.add_argument("--zoo", type=Path, default=Path(os.environ["MAPKIT_ZOO"]) if os.environ.get("MAPKIT_ZOO")
                        else None, help="a zoo.py --scratch folder (its SI_maribor/build is the region)")
    parser.add_argument("--duration", type=float, default=600.0, help="simulated seconds (default 600)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-peers", action="store_true", help="skip the load figures (ours and C++)")
    parser.add_argument("--json", type=Path, help="also write the rows here")
    parser.add_argument("--against", type=Path, help="also drive with this checkout's code (before/after)")
    parser.add_argument("--repeat", type=int, default=1, help="drives per build and code, the median reported")
    args = parser.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-twin-start-") as tmp:
        scratch = Path(tmp)
        builds = args.builds or default_builds(args.zoo, scratch)
        for build in builds:
            from twin.sim.build import Build

            xodr = Build.open(build).xodr
            # this code twice per attempt, from an empty route-plan cache: computing the plan (a map's first
            # drive) and reading it back (every later drive on the map); another checkout's before them
            variants = ([("before", args.against, False)] if args.against is not None else []) + \
                [("plan computed", None, False), ("plan kept", None, True)]
            runs: dict = {name: [] for name, _, _ in variants}
            for attempt in range(max(args.repeat, 1)):
                cache = scratch / f"plans-{len(rows)}-{attempt}"
                for name, code, _warm in variants:  # alternating: the machine's load falls on all alike
                    label = "this checkout" if code is None else str(code)
                    print(f"{build}: driving {args.duration:g} s with {label}, {name} ...", file=sys.stderr)
                    out = scratch / f"drive-{len(rows)}-{attempt}-{name.replace(' ', '-')}"
                    runs[name].append(drive(build, out, args.duration, args.seed, code, cache))
            for name, code, _warm in variants:
                metrics = _median_run(runs[name])
                row = {"build": str(build), "code": name if code is None else f"{name}: {code}",
                       "xodr_mb": xodr.stat().st_size / 1e6, "start_s": metrics["start_s"],
                       "setup_s": metrics["setup_seconds"], "rtf": metrics["real_time_factor"],
                       "command_s": metrics["command_s"], "resets": metrics["resets"],
                       "collisions": metrics["collisions"], "off_road_s": metrics["off_road_seconds"],
                       "twin": metrics["code"], "starts_s": [run["start_s"] for run in runs[name]],
                       "rtfs": [run["real_time_factor"] for run in runs[name]]}
                rows.append(row)
            if not args.no_peers:
                row["our_load_s"] = our_load(xodr)["seconds"]
                cpp = cpp_load(xodr)
                row["cpp_load_s"] = cpp["seconds"] if cpp else None
    head = ("build", "code", "xodr MB", "start s", "target", "real time", "target", "resets/coll/off-road s",
            "our load s", "C++ load s")
    print(" | ".join(head))
    print(" | ".join("---" for _ in head))
    for row in rows:
        cpp = row.get("cpp_load_s")
        print(" | ".join([
            Path(row["build"]).name if Path(row["build"]).name != "build" else Path(row["build"]).parent.name,
            row["code"], f"{row['xodr_mb']:.0f}", f"{row['start_s']:.1f}", f"<= {START_TARGET_S:.0f}",
            f"{row['rtf']:.0f}x",
            f">= {RTF_TARGET:.0f}x", f"{row['resets']}/{row['collisions']}/{row['off_road_s']:g}",
            f"{row['our_load_s']:.1f}" if "our_load_s" in row else "-",
            f"{cpp:.1f}" if cpp is not None else "-",
        ]))
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
