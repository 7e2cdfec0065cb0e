"""Does the twin slow its UDM requests down? ``twin udm bench`` against a local server on the DLR TAVF build.

    .venv/bin/python benchmarks/bench_udm_overhead.py [--build build/tavf-dlr] [--requests 300] [--rounds 2]

Starts ``twin udm serve --map BUILD`` as its own process on a free loopback port (so the server never
shares an interpreter with the twin), then runs ``twin udm bench`` -- a real drive with the UDM hook, and the
same requests sent standalone -- ``--rounds`` times, with the twin's client in a child process (the default)
and, as the peer, in a thread beside the simulation. Prints a table against the target overhead ratio
<= 1.05 and the JSON of every run. The build is made with ``mapkit build`` if it is missing.

Each round runs at every ``--pace`` (default: real time, then as fast as possible). At real time -- how a UDM is
tested with a car in the loop -- the ratio measures the twin's own overhead; unpaced, the simulation fills one
of the 2 reference cores and the server and client share the other, so the ratio mostly measures the machine.
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import time
from pathlib import Path

import httpx

REPO = Path(__file__).resolve().parents[1]
TAVF_NET = REPO.parent / "shared" / "data" / "hamburg" / "tavf_dlr_sumo_net" / "network.net.xml.gz"
TARGET = 1.05


def ensure_build(build: Path) -> Path:
    if (build / "collision" / "world.json").is_file():
        return build
    print(f"building {build} from {TAVF_NET} ...", flush=True)
    subprocess.run([sys.executable, "-m", "tavf_mapkit.cli.main", "build", str(TAVF_NET), "-o", str(build), "-q"],
                   check=True, cwd=REPO)
    return build


def start_server(build: Path, *options: str) -> tuple[subprocess.Popen, str]:
    """``twin udm serve --map BUILD`` on a free loopback port with ``options`` (e.g. --realtime): process, URL."""
    command = [sys.executable, "-m", "twin.cli.main", "udm", "serve", "--port", "0", "--map", str(build),
               "--token", "bench", *options]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, text=True, cwd=REPO)
    first = process.stdout.readline()
    match = re.search(r"http://\S+", first)
    if not match:
        process.kill()
        raise SystemExit(f"the UDM server did not start: {first!r}")
    url = match.group(0)
    deadline = time.monotonic() + 20.0
    while True:
        try:
            httpx.get(f"{url}/health", trust_env=False, timeout=1.0).raise_for_status()
            break
        except httpx.HTTPError:
            if time.monotonic() > deadline:
                process.kill()
                raise SystemExit("the UDM server did not answer /health") from None
            time.sleep(0.05)
    print(first.strip(), flush=True)
    return process, url


def run(build: Path, url: str, requests: int, client: str, pace: float | None) -> dict:
    command = [sys.executable, "-m", "twin.cli.main", "udm", "bench", "--map", str(build), "--url", url,
               "--requests", str(requests), "--client", client, "--json"]
    if pace:
        command += ["--pace", str(pace)]
    result = subprocess.run(command, capture_output=True, text=True, check=True, cwd=REPO)
    return json.loads(result.stdout[result.stdout.index("{"):])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--build", type=Path, default=REPO / "build" / "tavf-dlr")
    parser.add_argument("--requests", type=int, default=300)
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--pace", type=float, nargs="*", default=[1.0, 0.0],
                        help="twin speed limits to measure at, x real time (1 = real time, how a UDM is tested "
                             "with a car in the loop; 0 = as fast as possible, the twin then fills a core)")
    args = parser.parse_args()

    build = ensure_build(args.build)
    server, url = start_server(build)
    results = []
    try:
        for _ in range(args.rounds):
            for pace in args.pace:
                for client in ("process", "thread"):
                    results.append(run(build, url, args.requests, client, pace or None))
    finally:
        server.terminate()
        server.wait(10)

    print(f"\n{'pace':>5} {'client':8} {'standalone mean/p95 ms':>24} {'in twin mean/p95 ms':>22} {'available mean ms':>18} "
          f"{'ratio':>7} {'ratio p95':>9} {'RTF':>6}  target <= {TARGET}")
    for result in results:
        alone, twin, available = result["standalone_ms"], result["in_twin_ms"], result["in_twin_available_ms"]
        verdict = "ok" if result["overhead_ratio"] is not None and result["overhead_ratio"] <= TARGET else "MISS"
        pace = f"{result['pace']:g}x" if result.get("pace") else "free"
        print(f"{pace:>5} {result['client']:8} {alone['mean']:>12.2f} / {alone['p95']:<9.2f} {twin['mean']:>10.2f} / "
              f"{twin['p95']:<9.2f} {available['mean']:>18.2f} {result['overhead_ratio']:>7.3f} "
              f"{result['overhead_ratio_p95']:>9.3f} {result['twin']['real_time_factor']:>6}  {verdict}")
    print(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
