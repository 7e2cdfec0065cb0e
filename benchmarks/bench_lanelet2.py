"""The figures of docs/export.md's table of Lanelet2 exports: one build, exported and checked by the real library.

    $ nice -n 10 .venv/bin/python benchmarks/bench_lanelet2.py build/NAME/NAME.xodr --out /tmp/l2 [--json fig.json]

Two processes, one after the other, so each peak is its own: the export (load the OpenDRIVE, from the build's
NAME.odrmap when it is valid; ``export_lanelet2`` to OUT/NAME.osm, as ``mapkit export --to lanelet2`` does) and the check (load it again, load the .osm with
Lanelet2 and run the test's ``check_against_lanelet2`` -- the same function, imported from
tests/test_export_lanelet2.py, with the test's load-without-errors and routing-graph checks; a failed check
fails the run). Printed: lanelets, nodes, file size, load and export time, centre max / p99, lane-graph edges
Lanelet2 has, inside-out lanelets, peak RSS of each process (``ru_maxrss``, includes the loaded map).
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent

EXPORT = r"""
import json, resource, sys, time
from tavf_mapkit.opendrive.snapshot import load_build_map
from tavf_mapkit.lanelet2_export import export_lanelet2
xodr, osm = sys.argv[1], sys.argv[2]
t0 = time.perf_counter()
odr = load_build_map(xodr)  # a build's snapshot when it has one
t1 = time.perf_counter()
loaded = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
summary = export_lanelet2(odr, osm, name=xodr)
t2 = time.perf_counter()
print(json.dumps({"load_s": t1 - t0, "export_s": t2 - t1, "load_peak_rss_mib": loaded,
                  "export_peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                  **{k: v for k, v in summary.items() if k != "origin"}, "origin": list(summary["origin"])}))
"""

CHECK = r"""
import json, resource, sys, time
sys.path.insert(0, sys.argv[4])
import lanelet2
from test_export_lanelet2 import Lanelet2View, check_against_lanelet2
from tavf_mapkit.opendrive.snapshot import load_build_map
xodr, osm, origin = sys.argv[1], sys.argv[2], json.loads(sys.argv[3])
t0 = time.perf_counter()
odr = load_build_map(xodr)  # a build's snapshot when it has one
t1 = time.perf_counter()
view = Lanelet2View(lanelet2, osm, tuple(origin), odr)
t2 = time.perf_counter()
figures = check_against_lanelet2(view, starts=int(sys.argv[5]))
t3 = time.perf_counter()
print(json.dumps({"check_load_s": t1 - t0, "lanelet2_load_s": t2 - t1, "check_s": t3 - t2,
                  "check_peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                  "inside_out": len(view.inside_out()), **figures}))
"""


def _run(script: str, *arguments: str) -> dict:
    """One child process; its last stdout line is its JSON. A failure ends the benchmark with the child's
    last line of standard error (the failed check's assertion)."""
    done = subprocess.run([sys.executable, "-c", script, *arguments], capture_output=True, text=True, check=False)
    if done.returncode != 0:
        sys.exit(f"bench_lanelet2: {(done.stderr.strip().splitlines() or ['failed'])[-1]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("xodr", type=Path)
    parser.add_argument("--out", type=Path, required=True, help="folder for NAME.osm")
    parser.add_argument("--name", help="file name (default: the .xodr's stem)")
    parser.add_argument("--starts", type=int, default=8, help="start lanes of the reachable-set comparison")
    parser.add_argument("--no-check", action="store_true", help="export only")
    parser.add_argument("--json", type=Path, help="write the figures here too")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    osm = args.out / f"{args.name or args.xodr.stem}.osm"
    started = time.perf_counter()
    figures = {"xodr": str(args.xodr), "osm": str(osm), **_run(EXPORT, str(args.xodr), str(osm))}
    figures["file_bytes"] = osm.stat().st_size
    if not args.no_check:
        figures.update(_run(CHECK, str(args.xodr), str(osm), json.dumps(figures["origin"]), str(REPO / "tests"),
                            str(args.starts)))
    figures["wall_s"] = time.perf_counter() - started
    figures["children_peak_rss_mib"] = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    text = json.dumps(figures, indent=2)
    print(text)
    if args.json:
        args.json.write_text(text + "\n")
    row = (f"| {figures['lanelets']:,} | {figures['nodes']:,} | {figures['file_bytes'] / 1e6:.0f} MB | "
           f"{figures['export_s']:.1f} s |")
    if "centre_max" in figures:
        row += (f" {figures['centre_max'] * 1000:.1f} / {figures['centre_p99'] * 1000:.1f} mm | "
                f"{figures['edges'] - figures['missing_edges']:,} of {figures['edges']:,} | {figures['inside_out']} |")
    print(row, f"export peak {figures['export_peak_rss_mib']:,.0f} MiB", file=sys.stderr)


if __name__ == "__main__":
    main()
