"""A fleet of twins against one UDM: p95 UDM latency inside 20 twins driving at real time at once, against one
twin alone (issue 16: within 1.2x).

    $ .venv/bin/python benchmarks/bench_udm_fleet.py                     # the zoo's Perth roundabout, 60 s
    $ .venv/bin/python benchmarks/bench_udm_fleet.py --twins 20 --duration 120 --build build/tavf-dlr
    $ .venv/bin/python benchmarks/bench_udm_fleet.py --realtime          # the UDM path under SCHED_FIFO

Starts ``twin udm serve --map BUILD`` on a free loopback port (its own process), then
``twin sweep --udm URL`` (every run at real time, --pace 1): one seed alone, then ``--twins`` seeds on a
LocalCluster of as many workers, so all twins drive at once against the same server, then the one seed alone
again. With ``--realtime`` the server is started with ``--realtime`` and the sweeps with ``--udm-realtime``
(the request path under SCHED_FIFO, the simulations as they are; docs/distributed.md). The latency is the twin's request latency (fix sent -> answer parsed) of every successful query, pooled
over the runs from their udm_latency.csv; the ratio is the fleet's p95 over the lone twin's, whose queries are
pooled from before and after the fleet: on a machine shared with other jobs their load drifts within minutes,
and a lone run on one side of the fleet only would put all of that drift into the ratio (both lone runs' p95
are printed). The overlap column is the sum of the runs' wall times over the sweep's: near the number of twins
when they really drove at the same time.

Where the latency goes: every query's row has the server's own time (its Server-Timing header: request reached
the app -> answer ready) and the client's wait for a core during the request (schedstat); the rest is the
network, uvicorn's HTTP parsing, the client's own CPU and the server's wait for a core. While the sweep runs,
the server process's CPU and run-queue wait (/proc/PID/schedstat) and the machine's CPU use and runnable tasks
(/proc/stat) are sampled, and reported per request and for the window in which every twin drives.
"""

from __future__ import annotations

import argparse
import csv
import importlib.util
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Self

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from bench_udm_overhead import start_server

REPO = HERE.parent
SHARED = Path(os.environ.get("TAVF_SHARED_DATA", REPO.parent / "shared" / "data"))
PERTH = SHARED / "zoo" / "osm" / "AU_perth_peanut_roundabout_LHT.osm.gz"
BIN = Path(sys.executable).parent
TARGET = 1.2
BURST_S = 0.005  # a request sent this soon after another twin's counts as arriving with it


class Sampler:
    """Samples, every ``interval_s`` on a thread, the server process's CPU and run-queue wait (schedstat, summed
    over its threads) and the machine's busy CPU seconds and runnable tasks (/proc/stat), against
    time.monotonic, so a window of the sweep can be cut out afterwards."""

    def __init__(self, pid: int, interval_s: float = 0.25) -> None:
        self.pid, self.interval_s = pid, interval_s
        # t, server cpu, server wait, server preempted (involuntary context switches), busy, runnable
        self.samples: list[tuple[float, float, float, int, float, int]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self) -> Self:
        self._thread.start()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self._stop.set()
        self._thread.join()

    def _run(self) -> None:
        while True:
            self.samples.append((time.monotonic(), *self.server(), *machine()))
            if self._stop.wait(self.interval_s):
                return

    def server(self) -> tuple[float, float, int]:
        cpu = wait = preempted = 0
        for task in Path(f"/proc/{self.pid}/task").iterdir():
            try:
                fields = (task / "schedstat").read_text().split()
                status = (task / "status").read_text()
            except OSError:  # a thread that just ended
                continue
            cpu, wait = cpu + int(fields[0]), wait + int(fields[1])
            preempted += int(status.split("nonvoluntary_ctxt_switches:")[1].split()[0])
        return cpu / 1e9, wait / 1e9, preempted

    def between(self, start: float, end: float) -> dict | None:
        """Server CPU and wait seconds, machine busy cores and mean runnable tasks from ``start`` to ``end``."""
        inside = [sample for sample in self.samples if start <= sample[0] <= end]
        if len(inside) < 2:
            return None
        first, last = inside[0], inside[-1]
        span = last[0] - first[0]
        return {"s": span, "server_cpu_s": last[1] - first[1], "server_wait_s": last[2] - first[2],
                "server_preempted": last[3] - first[3], "busy_cores": (last[4] - first[4]) / span,
                "runnable": float(np.mean([sample[5] for sample in inside]))}


def machine() -> tuple[float, int]:
    """Busy CPU seconds of the whole machine since boot (all but idle and iowait) and the runnable tasks now."""
    busy, runnable = 0.0, 0
    for line in Path("/proc/stat").read_text().splitlines():
        fields = line.split()
        if fields[0] == "cpu":
            ticks = [int(value) for value in fields[1:]]
            busy = (sum(ticks[:8]) - ticks[3] - ticks[4]) / os.sysconf("SC_CLK_TCK")
        elif fields[0] == "procs_running":
            runnable = int(fields[1])
    return busy, runnable


def percentiles(values: list[float]) -> dict | None:
    if not values:
        return None
    return {"p50_ms": float(np.percentile(values, 50)), "p95_ms": float(np.percentile(values, 95))}


def sweep(build: Path, url: str, twins: int, duration: float, out: Path, server_pid: int,
          realtime: bool = False) -> dict:
    command = [str(BIN / "twin"), "sweep", "--map", str(build), "--seeds", f"0-{twins - 1}", "--duration",
               str(duration), "--udm", url, "-o", str(out), "-q", *(["--udm-realtime"] if realtime else [])]
    if twins > 1:
        command += ["--workers", str(twins)]
    started = time.perf_counter()
    with Sampler(server_pid) as sampler:
        subprocess.run(command, check=True, capture_output=True)
    wall = time.perf_counter() - started
    sent, latency, spans, server_ms, wait_ms, rest_ms, all_sent = [], [], [], [], [], [], []
    for path in sorted((out / "runs").glob("seed-*/udm_latency.csv")):
        with path.open() as handle:
            every = list(csv.DictReader(handle))
        all_sent += [float(row["t_sent"]) for row in every if row["t_sent"]]
        rows = [row for row in every if row["status"] == "ok" and row["client_latency_s"]]
        sent += [float(row["t_sent"]) for row in rows]
        latency += [float(row["client_latency_s"]) * 1000 for row in rows]
        for row in rows:
            known = row.get("server_s") and row.get("client_wait_s")
            server_ms.append(float(row["server_s"]) * 1000 if known else np.nan)
            wait_ms.append(float(row["client_wait_s"]) * 1000 if known else np.nan)
            rest_ms.append(latency[len(server_ms) - 1] - server_ms[-1] - wait_ms[-1] if known else np.nan)
        if rows:
            spans.append((float(rows[0]["t_sent"]), float(rows[-1]["t_sent"])))
    report = json.loads((out / "sweep.json").read_text())
    runs = report["runs"]
    values, sent = np.asarray(latency), np.asarray(sent)
    # while every twin drives (time.monotonic is one clock for all processes of the machine): after the last
    # one's first query, before the first one's last; the twins' start-up (map loading) lies outside
    start, end = max(span[0] for span in spans), min(span[1] for span in spans)
    inside = (sent >= start) & (sent <= end)
    steady = values[inside]
    samples = {}  # the queries the parts describe, kept so lone runs can be pooled (pooled_alone)
    for name, series in (("request", values), ("server", np.asarray(server_ms)), ("client_wait", np.asarray(wait_ms)),
                         ("rest", np.asarray(rest_ms))):
        part = series[inside] if twins > 1 else series  # a lone twin: its whole run
        samples[name] = [float(value) for value in part if np.isfinite(value)]
    parts = {name: percentiles(series) for name, series in samples.items()}
    crowding = bursts(np.asarray(all_sent), sent, values, inside) if twins > 1 else None
    window = sampler.between(start, end) if twins > 1 else sampler.between(spans[0][0], spans[0][1])
    if window:
        served = sum(1 for t in all_sent if (start if twins > 1 else spans[0][0]) <= t
                     <= (end if twins > 1 else spans[0][1]))
        window["requests"] = served
        window["server_cpu_ms_per_request"] = 1000 * window["server_cpu_s"] / max(1, served)
        window["server_wait_ms_per_request"] = 1000 * window["server_wait_s"] / max(1, served)
        window["server_preempted_per_request"] = window["server_preempted"] / max(1, served)
    return {"twins": twins, "wall_s": wall, "queries": len(values), "parts": parts, "samples": samples,
            "window": window,
            "p50_ms": float(np.percentile(values, 50)), "p95_ms": float(np.percentile(values, 95)),
            "p99_ms": float(np.percentile(values, 99)),
            "all_driving_s": max(0.0, end - start), "all_driving_queries": len(steady),
            "all_driving_p95_ms": float(np.percentile(steady, 95)) if len(steady) else None, "bursts": crowding,
            "overlap": sum(run["wall_s"] for run in runs) / wall,
            "ok": report["summary"]["ok"], "errors": sum(run["udm_errors"] or 0 for run in runs),
            "rtf": [run["real_time_factor"] for run in runs]}


def pooled_alone(runs: list[dict]) -> dict:
    """The lone twin's runs as one: their queries pooled for the percentiles and the parts, their windows and
    real-time factors side by side."""
    samples = {name: [value for run in runs for value in run["samples"][name]] for name in runs[0]["samples"]}
    latency = samples["request"]
    return {"twins": 1, "wall_s": sum(run["wall_s"] for run in runs), "queries": len(latency),
            "parts": {name: percentiles(series) for name, series in samples.items()}, "samples": samples,
            "windows": [run["window"] for run in runs],
            "p50_ms": float(np.percentile(latency, 50)), "p95_ms": float(np.percentile(latency, 95)),
            "p99_ms": float(np.percentile(latency, 99)), "all_driving_s": sum(run["all_driving_s"] for run in runs),
            "all_driving_queries": len(latency), "all_driving_p95_ms": float(np.percentile(latency, 95)),
            "bursts": None, "overlap": 1.0, "ok": sum(run["ok"] for run in runs),
            "errors": sum(run["errors"] for run in runs), "rtf": [rtf for run in runs for rtf in run["rtf"]],
            "runs_p95_ms": [run["p95_ms"] for run in runs]}


def bursts(every_sent: np.ndarray, sent: np.ndarray, latency: np.ndarray, inside: np.ndarray) -> dict | None:
    """Do the twins' queries arrive together? For the requests sent while all drive: the share sent within
    BURST_S after another twin's request, and the p95 latency of those and of the others. The twins start
    their drives as their maps finish loading, so their query times are phased at random: if that share were
    high, requests would queue behind one another in the server."""
    ordered = np.sort(every_sent)
    earlier = np.searchsorted(ordered, sent[inside], side="left") - np.searchsorted(
        ordered, sent[inside] - BURST_S, side="left")
    crowded = earlier > 0
    if not len(crowded):
        return None
    return {"window_ms": BURST_S * 1000, "share": float(crowded.mean()),
            "crowded_p95_ms": float(np.percentile(latency[inside][crowded], 95)) if crowded.any() else None,
            "alone_p95_ms": float(np.percentile(latency[inside][~crowded], 95)) if (~crowded).any() else None}


def print_breakdown(alone: dict, fleet: dict) -> None:
    """Where the latency goes, the lone twin's whole run against the fleet's window in which all drive."""
    def cell(row: dict, name: str) -> str:
        part = row["parts"].get(name)
        return f"{part['p50_ms']:>7.2f} {part['p95_ms']:>7.2f}" if part else f"{'-':>7} {'-':>7}"

    print(f"\n{'where the request latency goes (ms)':<58} {'1 twin p50':>10} {'p95':>5}  "
          f"{fleet['twins']} twins p50     p95")
    labels = {"request": "request: fix sent -> answer parsed (the metric)",
              "server": "server-side: request in the app -> answer (Server-Timing)",
              "client_wait": "client process waiting for a core (schedstat)",
              "rest": "rest: network, uvicorn, client CPU, server waiting"}
    for name, label in labels.items():
        print(f"{label:<58} {cell(alone, name)}  {cell(fleet, name)}")
    print(f"{'(percentiles of each part taken alone: the parts do not add up)':<58}")
    crowding = fleet.get("bursts")
    if crowding:
        print(f"{fleet['twins']} twins: {100 * crowding['share']:.0f} % of the requests were sent within "
              f"{crowding['window_ms']:.0f} ms after another twin's (p95 {crowding['crowded_p95_ms'] or float('nan'):.2f} ms; "
              f"the others {crowding['alone_p95_ms'] or float('nan'):.2f} ms)")
    windows = [(f"1 twin, {when}", window) for when, window in zip(("before", "after"), alone["windows"])]
    for name, window in [*windows, (f"{fleet['twins']} twins", fleet["window"])]:
        if not window:
            continue
        print(f"{name}, {window['s']:.0f} s: server process {window['server_cpu_ms_per_request']:.2f} ms "
              f"CPU, {window['server_wait_ms_per_request']:.2f} ms waiting for a core and "
              f"{window['server_preempted_per_request']:.2f} preemptions per request "
              f"({window['requests']} requests); machine {window['busy_cores']:.2f} of {os.cpu_count()} cores busy, "
              f"{window['runnable']:.1f} tasks runnable on average")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--build", type=Path, help="a build folder (default: build the zoo's Perth roundabout)")
    parser.add_argument("--twins", type=int, default=20)
    parser.add_argument("--duration", type=float, default=60.0)
    parser.add_argument("--realtime", action="store_true",
                        help="the UDM path under SCHED_FIFO: `twin udm serve --realtime`, `twin sweep --udm-realtime`")
    args = parser.parse_args()
    print("load average before:", " ".join(Path("/proc/loadavg").read_text().split()[:3]), flush=True)
    # uvicorn picks httptools and uvloop by itself when they are installed (uvicorn[standard]); the server
    # runs in this interpreter's environment, so what is importable here is what it parses HTTP with
    fast = all(importlib.util.find_spec(name) for name in ("httptools", "uvloop"))
    print("UDM server's HTTP:", "httptools on uvloop" if fast else "h11 on asyncio (uvicorn[standard] not installed)")
    with tempfile.TemporaryDirectory(prefix="bench-udm-fleet-") as scratch:
        scratch = Path(scratch)
        build = args.build
        if build is None:
            build = scratch / "perth"
            subprocess.run([str(BIN / "mapkit"), "build", str(PERTH), "-o", str(build), "-q"], check=True,
                           capture_output=True)
        server, url = start_server(build, *(["--realtime"] if args.realtime else []))
        print("UDM path's scheduling: " + ("SCHED_FIFO (server --realtime, clients --udm-realtime; the "
                                           "simulations as before)" if args.realtime else "normal"), flush=True)
        try:
            runs = {name: sweep(build, url, twins, args.duration, scratch / name, server.pid, args.realtime)
                    for name, twins in (("alone-before", 1), ("fleet", args.twins), ("alone-after", 1))}
            before, fleet, after = runs["alone-before"], runs["fleet"], runs["alone-after"]
        finally:
            server.terminate()
            server.wait(10)
    alone = pooled_alone([before, after])
    ratio = fleet["p95_ms"] / alone["p95_ms"]
    steady = fleet["all_driving_p95_ms"]
    print(f"\n{'twins':>5} {'queries':>8} {'p50 ms':>7} {'p95 ms':>7} {'p99 ms':>7} {'errors':>6} {'overlap':>7} "
          f"{'all driving: s, queries, p95 ms':>32}  real-time factors")
    for row in (alone, fleet):
        print(f"{row['twins']:>5} {row['queries']:>8} {row['p50_ms']:>7.2f} {row['p95_ms']:>7.2f} "
              f"{row['p99_ms']:>7.2f} {row['errors']:>6} {row['overlap']:>7.1f} {row['all_driving_s']:>13.1f} "
              f"{row['all_driving_queries']:>8} {row['all_driving_p95_ms'] or float('nan'):>9.2f}  "
              f"{min(row['rtf']):.2f}-{max(row['rtf']):.2f}")
    print(f"(1 twin: p95 {before['p95_ms']:.2f} ms before the fleet, {after['p95_ms']:.2f} ms after; pooled above)")
    verdict = "ok" if ratio <= TARGET else "MISS"
    print(f"\np95 of {args.twins} twins at once / one twin alone: {ratio:.2f}x over the whole sweep, "
          + (f"{steady / alone['p95_ms']:.2f}x while all drive" if steady else "never all driving at once")
          + f" (target <= {TARGET}x) {verdict}")
    print_breakdown(alone, fleet)
    print("load average after:", " ".join(Path("/proc/loadavg").read_text().split()[:3]))
    for row in (alone, fleet):
        row.pop("samples")
    print(json.dumps({"realtime": args.realtime, "alone": alone, "fleet": fleet, "ratio_p95": ratio}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
