"""How fast does the local UDM answer a fleet? 50 vehicles at 10 Hz against ``twin udm serve``.

    $ .venv/bin/python benchmarks/bench_udm_load.py                 # 60 s, the figure for the record
    $ .venv/bin/python benchmarks/bench_udm_load.py --duration 10   # a quick look

The server runs in its own process (as in a real deployment) on a free loopback port, filled with random
objects around Hamburg; the fleet runs in this process (see twin/udm/loadgen.py). The target is the
issue's: p95 latency <= 20 ms, measured at the client from request sent to JSON parsed.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import queue
import random
import re
import secrets
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx

from twin.udm.loadgen import HAMBURG, LoadPlan, run_load
from twin.udm.model import EARTH_RADIUS_M

REPO = Path(__file__).resolve().parents[1]

TARGET_P95_MS = 20.0
TYPES = (("traffic_signals", 2), ("traffic_sign", 2), ("roadworks", 3), ("vehicle", 4), ("pedestrian", 4))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=60.0, help="seconds of load (default 60)")
    parser.add_argument("--vehicles", type=int, default=50)
    parser.add_argument("--rate", type=float, default=10.0, help="queries per second per vehicle")
    parser.add_argument("--objects", type=int, default=20_000, help="random objects seeded around Hamburg")
    parser.add_argument("--area-radius", type=float, default=3000.0, help="metres around the centre")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    token = secrets.token_urlsafe(16)
    with tempfile.TemporaryFile("w+") as server_log, ServerProcess(token, server_log) as url:
        seed_random_objects(url, token, args.objects, args.area_radius, args.seed)
        plan = LoadPlan(url=url, vehicles=args.vehicles, rate_hz=args.rate, duration_s=args.duration,
                        lat=HAMBURG[0], lon=HAMBURG[1], area_radius_m=args.area_radius, seed=args.seed)
        report = run_load(plan)
    print_table(args, report)


class ServerProcess:
    """``twin udm serve --port 0`` in a subprocess; yields its URL, stops it on exit."""

    def __init__(self, token: str, log) -> None:
        command = [sys.executable, "-m", "twin.cli.main", "udm", "serve", "--port", "0"]
        env = {**os.environ, "TWIN_UDM_TOKEN": token, "PYTHONPATH": str(REPO)}
        self.process = subprocess.Popen(command, cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=log,
                                        text=True)

    def __enter__(self) -> str:
        lines: queue.Queue[str] = queue.Queue()
        threading.Thread(target=lambda: lines.put(self.process.stdout.readline()), daemon=True).start()
        try:
            first = lines.get(timeout=30)
        except queue.Empty:
            self.__exit__()
            raise SystemExit("the UDM server printed no URL within 30 s") from None
        match = re.search(r"http://127\.0\.0\.1:\d+", first)
        if not match:
            self.__exit__()
            raise SystemExit(f"the UDM server did not start: {first!r}")
        url = match.group(0)
        deadline = time.monotonic() + 30
        while True:  # the URL is printed just before uvicorn accepts connections
            try:
                httpx.get(f"{url}/health", trust_env=False).raise_for_status()
                return url
            except httpx.HTTPError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.05)

    def __exit__(self, *exc_info: object) -> None:
        self.process.terminate()
        try:
            self.process.wait(10)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()


def seed_random_objects(url: str, token: str, count: int, area_radius_m: float, seed: int) -> None:
    """``count`` objects spread uniformly over a disc a little wider than the fleet's area."""
    rng = random.Random(seed)
    radius_m = area_radius_m + 500.0
    parallel = math.cos(math.radians(HAMBURG[0]))  # metres per metre of a parallel vs. the equator
    features = []
    for index in range(count):
        distance, bearing = radius_m * math.sqrt(rng.random()), rng.uniform(0.0, 2 * math.pi)
        lat = HAMBURG[0] + math.degrees(distance * math.cos(bearing) / EARTH_RADIUS_M)
        lon = HAMBURG[1] + math.degrees(distance * math.sin(bearing) / (EARTH_RADIUS_M * parallel))
        type_, layer = rng.choice(TYPES)
        features.append({"type": "Feature", "id": f"bench-{index}",
                         "geometry": {"type": "Point", "coordinates": [lon, lat]},
                         "properties": {"layer": layer, "type": type_, "heading": rng.uniform(0, 360),
                                        "source": "bench_udm_load"}})
    with httpx.Client(base_url=url, trust_env=False, timeout=60.0,
                      headers={"Authorization": f"Bearer {token}"}) as http:
        for start in range(0, count, 5000):
            batch = {"type": "FeatureCollection", "features": features[start:start + 5000]}
            http.post("/objects", json=batch).raise_for_status()


def print_table(args: argparse.Namespace, report: dict) -> None:
    latency = report["latency_ms"]
    p95 = latency["p95"]
    print(f"UDM load: {args.vehicles} vehicles x {args.rate:g} Hz x {args.duration:g} s, "
          f"{args.objects} objects around Hamburg, 200 m query squares")
    print(f"server: twin udm serve (SQLite R*Tree, uvicorn) in a subprocess; "
          f"{platform.python_implementation()} {platform.python_version()}, {os.cpu_count()} CPUs")
    print()
    rows = [
        ("requests", f"{report['requests']}"),
        ("errors", f"{report['errors']}" + (f"  {report['errors_by_kind']}" if report["errors"] else "")),
        ("skipped ticks", f"{report['skipped_ticks']}"),
        ("achieved rate", f"{report['achieved_rate_hz']:.0f} req/s"),
        ("objects per answer", f"{report['objects_per_response']:.1f}"),
        ("p50 latency", fmt_ms(latency["p50"])),
        ("p95 latency", fmt_ms(p95)),
        ("max latency", fmt_ms(latency["max"])),
        ("target p95", fmt_ms(TARGET_P95_MS)),
        ("p95 / target", "n/a" if p95 is None else f"{p95 / TARGET_P95_MS:.2f}"
         + ("  (meets target)" if p95 <= TARGET_P95_MS else "  (MISSES target)")),
    ]
    width = max(len(name) for name, _ in rows)
    for name, value in rows:
        print(f"{name:<{width}}  {value}")


def fmt_ms(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.2f} ms"


if __name__ == "__main__":
    main()
