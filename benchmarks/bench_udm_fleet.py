"""A fleet of twins against one UDM: p95 UDM latency inside 20 twins driving at real time at once, against one
twin alone (issue 16: within 1.2x).

    $ .venv/bin/python benchmarks/bench_udm_fleet.py                     # the zoo's Perth roundabout, 60 s
    $ .venv/bin/python benchmarks/bench_udm_fleet.py --twins 20 --duration 120 --build build/tavf-dlr

Starts ``twin udm serve --map BUILD`` on a free loopback port (its own process), then
``twin sweep --udm URL`` (every run at real time, --pace 1): first one seed alone, then ``--twins`` seeds on a
LocalCluster of as many workers, so all twins drive at once against the same server. The latency is the twin's
request latency (fix sent -> answer parsed) of every successful query, pooled over the runs from their
udm_latency.csv; the ratio is the fleet's p95 over the lone twin's. The overlap column is the sum of the runs'
wall times over the sweep's: near the number of twins when they really drove at the same time.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from bench_udm_overhead import start_server

REPO = HERE.parent
SHARED = Path(os.environ.get("TAVF_SHARED_DATA", REPO.parent / "shared" / "data"))
PERTH = SHARED / "zoo" / "osm" / "AU_perth_peanut_roundabout_LHT.osm.gz"
BIN = Path(sys.executable).parent
TARGET = 1.2


def sweep(build: Path, url: str, twins: int, duration: float, out: Path) -> dict:
    command = [str(BIN / "twin"), "sweep", "--map", str(build), "--seeds", f"0-{twins - 1}", "--duration",
               str(duration), "--udm", url, "-o", str(out), "-q"]
    if twins > 1:
        command += ["--workers", str(twins)]
    started = time.perf_counter()
    subprocess.run(command, check=True, capture_output=True)
    wall = time.perf_counter() - started
    sent, latency, spans = [], [], []
    for path in sorted((out / "runs").glob("seed-*/udm_latency.csv")):
        with path.open() as handle:
            rows = [row for row in csv.DictReader(handle) if row["status"] == "ok" and row["client_latency_s"]]
        sent += [float(row["t_sent"]) for row in rows]
        latency += [float(row["client_latency_s"]) * 1000 for row in rows]
        if rows:
            spans.append((float(rows[0]["t_sent"]), float(rows[-1]["t_sent"])))
    report = json.loads((out / "sweep.json").read_text())
    runs = report["runs"]
    values, sent = np.asarray(latency), np.asarray(sent)
    # while every twin drives (time.monotonic is one clock for all processes of the machine): after the last
    # one's first query, before the first one's last; the twins' start-up (map loading) lies outside
    start, end = max(span[0] for span in spans), min(span[1] for span in spans)
    steady = values[(sent >= start) & (sent <= end)]
    return {"twins": twins, "wall_s": wall, "queries": len(values),
            "p50_ms": float(np.percentile(values, 50)), "p95_ms": float(np.percentile(values, 95)),
            "p99_ms": float(np.percentile(values, 99)),
            "all_driving_s": max(0.0, end - start), "all_driving_queries": len(steady),
            "all_driving_p95_ms": float(np.percentile(steady, 95)) if len(steady) else None,
            "overlap": sum(run["wall_s"] for run in runs) / wall,
            "ok": report["summary"]["ok"], "errors": sum(run["udm_errors"] or 0 for run in runs),
            "rtf": [run["real_time_factor"] for run in runs]}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--build", type=Path, help="a build folder (default: build the zoo's Perth roundabout)")
    parser.add_argument("--twins", type=int, default=20)
    parser.add_argument("--duration", type=float, default=60.0)
    args = parser.parse_args()
    print("load average before:", " ".join(Path("/proc/loadavg").read_text().split()[:3]), flush=True)
    with tempfile.TemporaryDirectory(prefix="bench-udm-fleet-") as scratch:
        scratch = Path(scratch)
        build = args.build
        if build is None:
            build = scratch / "perth"
            subprocess.run([str(BIN / "mapkit"), "build", str(PERTH), "-o", str(build), "-q"], check=True,
                           capture_output=True)
        server, url = start_server(build)
        try:
            alone = sweep(build, url, 1, args.duration, scratch / "alone")
            fleet = sweep(build, url, args.twins, args.duration, scratch / "fleet")
        finally:
            server.terminate()
            server.wait(10)
    ratio = fleet["p95_ms"] / alone["p95_ms"]
    steady = fleet["all_driving_p95_ms"]
    print(f"\n{'twins':>5} {'queries':>8} {'p50 ms':>7} {'p95 ms':>7} {'p99 ms':>7} {'errors':>6} {'overlap':>7} "
          f"{'all driving: s, queries, p95 ms':>32}  real-time factors")
    for row in (alone, fleet):
        print(f"{row['twins']:>5} {row['queries']:>8} {row['p50_ms']:>7.2f} {row['p95_ms']:>7.2f} "
              f"{row['p99_ms']:>7.2f} {row['errors']:>6} {row['overlap']:>7.1f} {row['all_driving_s']:>13.1f} "
              f"{row['all_driving_queries']:>8} {row['all_driving_p95_ms'] or float('nan'):>9.2f}  "
              f"{min(row['rtf']):.2f}-{max(row['rtf']):.2f}")
    verdict = "ok" if ratio <= TARGET else "MISS"
    print(f"\np95 of {args.twins} twins at once / one twin alone: {ratio:.2f}x over the whole sweep, "
          + (f"{steady / alone['p95_ms']:.2f}x while all drive" if steady else "never all driving at once")
          + f" (target <= {TARGET}x) {verdict}")
    print("load average after:", " ".join(Path("/proc/loadavg").read_text().split()[:3]))
    print(json.dumps({"alone": alone, "fleet": fleet, "ratio_p95": ratio}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
