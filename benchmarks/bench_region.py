"""Region scale: build time and peak memory against road count, next to netconvert and the C++ reader.

    $ .venv/bin/python benchmarks/bench_region.py                         # grids 8, 16, 32, 60 + the TAVF net
    $ .venv/bin/python benchmarks/bench_region.py --grids 6,12 --json benchmarks/results/region.json
    $ .venv/bin/python benchmarks/bench_region.py --xodr /tmp/big.xodr    # load figures of any OpenDRIVE file only
    $ .venv/bin/python benchmarks/bench_region.py --xodr /tmp/big.xodr --grids 60   # ... and a region build

For each synthetic region of sample_data/make_region.py (``--grids``: crossings per side; 60 is about 50,000
OpenDRIVE roads) and for DLR's TAVF SUMO network it runs, in the same run and each in its own process group:
- ``mapkit build`` (all stages): wall time, peak RSS of the whole process tree, seconds per stage; netconvert's
  own seconds are its stage's (the build runs netconvert once, as a child), so "build / netconvert" is the
  ratio issue 15 asks for (target: the TAVF net within 4x; a 50,000-road region within 5 minutes and 4 GB);
- loading the build's OpenDRIVE: our reader (``load_opendrive``, after its imports: Python's start-up is not
  the reader's) against the C++ evaluator of
  ../shared/tools/libopendrive (its dump tool with a step longer than any road: parse + one sample per lane),
  wall time and peak RSS of each (target: within 2x of C++ on both).
The table is the curve of time and peak RSS against road count that shows whether memory grows with the map or
with the tile. Figures are from a shared 2-core machine: compare the ratios within one run.
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
from peers import PeerUnavailable, libopendrive  # noqa: E402
from zoo import run_limited  # noqa: E402  (process-group limits and tree RSS, one place)

SHARED = REPO.parent / "shared" / "data"
TAVF_NET = SHARED / "hamburg" / "tavf_dlr_sumo_net" / "network.net.xml.gz"
BIN = Path(sys.executable).parent

OUR_LOAD = r"""
import json, resource, sys, time
t0 = time.perf_counter()
from tavf_mapkit.opendrive.reader import load_opendrive
t1 = time.perf_counter()
odr = load_opendrive(sys.argv[1])
print(json.dumps({"seconds": time.perf_counter() - t1, "import_s": t1 - t0, "roads": len(odr.roads),
                  "peak_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def our_load(xodr: Path) -> dict:
    done = subprocess.run([sys.executable, "-c", OUR_LOAD, str(xodr)], capture_output=True, text=True, check=True)
    return json.loads(done.stdout)


def cpp_load(xodr: Path) -> dict | None:
    try:
        program = libopendrive.binary()
    except PeerUnavailable as why:
        print(f"  (no C++ figures: {why})", file=sys.stderr)
        return None
    start = time.perf_counter()
    process = subprocess.Popen([str(program), str(xodr), "1e12"], stdout=subprocess.DEVNULL)
    _, status, usage = os.wait4(process.pid, 0)  # this child's own rusage, not the largest child's so far
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"{program} {xodr}: exit {os.waitstatus_to_exitcode(status)}")
    return {"seconds": time.perf_counter() - start, "peak_mib": usage.ru_maxrss / 1024}


def build(source: Path, folder: Path, timeout: float, memory_mib: float) -> dict:
    result = run_limited([str(BIN / "mapkit"), "build", str(source), "-o", str(folder), "-q"], timeout, memory_mib)
    row = {"exit": result.code, "wall_s": result.wall, "peak_mib": result.peak_rss_mib}
    if result.code != 0:
        row["reason"] = result.reason
        return row
    manifest = json.loads((folder / "manifest.json").read_text())
    row["stages"] = {stage["name"]: stage.get("seconds") for stage in manifest["stages"]}
    row["beside"] = [stage["name"] for stage in manifest["stages"] if stage.get("beside")]
    row["netconvert_s"] = row["stages"].get("netconvert")
    xodr = next(folder.glob("*.xodr"))
    row["xodr"] = str(xodr)
    return row


def measure(name: str, source: Path, scratch: Path, args) -> dict:
    folder = scratch / name
    row = {"name": name, **build(source, folder, args.timeout, args.memory_mib)}
    if row["exit"] == 0:
        xodr = Path(row["xodr"])
        row["cpp_load"] = cpp_load(xodr)
        row["our_load"] = our_load(xodr)
        row["roads"] = row["our_load"]["roads"]
    return row


def ratio(a, b) -> str:
    return f"{a / b:.1f}x" if a and b else "-"


def stage_seconds(row: dict) -> str:
    """The seconds of the stages after netconvert, e.g. "opendrive 120 / mesh 258 / check 73 (beside) / ..."."""
    shown = [(name, seconds) for name, seconds in row["stages"].items()
             if name not in ("extract", "netconvert") and seconds is not None]
    return " / ".join(f"{name} {seconds:.1f}" + (" (beside)" if name in row.get("beside", ()) else "")
                      for name, seconds in shown) or "-"


def print_table(rows: list[dict]) -> None:
    head = ("input", "roads", "netconvert s", "build s", "build/netc", "build MiB", "stages s", "our load s",
            "C++ load s", "load ratio", "our load MiB", "C++ MiB", "MiB ratio")
    print(" | ".join(head))
    print(" | ".join("---" for _ in head))
    for row in rows:
        if row["exit"] != 0:
            print(f"{row['name']} | FAILED ({row['wall_s']:.0f} s, {row['peak_mib']:.0f} MiB): {row.get('reason')}")
            continue
        ours, cpp = row["our_load"], row.get("cpp_load") or {}
        print(" | ".join([
            row["name"], str(row["roads"]), f"{row['netconvert_s']:.1f}", f"{row['wall_s']:.1f}",
            ratio(row["wall_s"], row["netconvert_s"]), f"{row['peak_mib']:.0f}", stage_seconds(row),
            f"{ours['seconds']:.2f}", f"{cpp.get('seconds', float('nan')):.2f}", ratio(ours["seconds"], cpp.get("seconds")),
            f"{ours['peak_mib']:.0f}", f"{cpp.get('peak_mib', float('nan')):.0f}",
            ratio(ours["peak_mib"], cpp.get("peak_mib")),
        ]))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--grids", help="region sizes: crossings per side, comma-separated (default 8,16,32,60; "
                                         "none with --xodr)")
    parser.add_argument("--no-tavf", action="store_true", help="skip DLR's TAVF network (skipped with --xodr "
                                                               "unless --grids is given)")
    parser.add_argument("--xodr", type=Path, action="append", default=[],
                        help="also load this OpenDRIVE file with both readers (no build)")
    parser.add_argument("--timeout", type=float, default=1800, help="wall-time limit of one build (s)")
    parser.add_argument("--memory-mib", type=float, default=8192, help="memory limit of one build (MiB)")
    parser.add_argument("--scratch", type=Path, help="where regions and builds go (default: a temporary folder)")
    parser.add_argument("--json", type=Path, help="also write the rows as JSON here")
    args = parser.parse_args(argv)
    scratch = args.scratch or Path(tempfile.mkdtemp(prefix="mapkit-region-"))
    scratch.mkdir(parents=True, exist_ok=True)
    rows = []
    for xodr in args.xodr:  # load figures only
        rows.append({"name": xodr.name, "exit": 0, "wall_s": 0.0, "peak_mib": 0.0, "netconvert_s": 0.0,
                     "stages": {}, "cpp_load": cpp_load(xodr), "our_load": our_load(xodr)})
        rows[-1]["roads"] = rows[-1]["our_load"]["roads"]
    loads_only = args.xodr and args.grids is None  # --xodr FILE alone: the load figures, no builds
    grids = "" if loads_only else args.grids if args.grids is not None else "8,16,32,60"
    sources = [] if args.no_tavf or loads_only or not TAVF_NET.is_file() else [("tavf-net", TAVF_NET)]
    for grid in [int(g) for g in grids.split(",") if g.strip()]:
        osm = scratch / f"region-{grid}.osm"
        if not osm.is_file():
            subprocess.run([sys.executable, str(REPO / "sample_data" / "make_region.py"), "--grid", str(grid),
                            "-o", str(osm)], check=True, stdout=subprocess.DEVNULL)
        sources.append((f"region-{grid}", osm))
    for name, source in sources:
        print(f"building {name} ...", file=sys.stderr, flush=True)
        rows.append(measure(name, source, scratch, args))
    print_table(rows)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(rows, indent=1) + "\n")
    return 0 if all(row["exit"] == 0 for row in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
