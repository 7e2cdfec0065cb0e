"""mapkit validate vs the ASAM Quality Checker's OpenDRIVE bundle (asam-qc-opendrive), same files, same run.

    $ .venv/bin/python benchmarks/bench_validate.py [--repeat 3] [--no-peers]

Files: netconvert's OpenDRIVE of DLR's TAVF network (made here with the eclipse-sumo wheel), CARLA's Town07
(libOpenDRIVE's test file) and, when present, the Jungfernstieg build (build/jungfernstieg). Target (TAVF):
validate_file <= 2 s. asam-qc-opendrive pins numpy < 2, so it runs in its own venv (benchmarks/.peers/qc,
created on first use); its time is the whole process (it has no library entry point that skips the CLI), ours is
given both in-process and as a whole process. Findings are printed side by side: ours by rule and severity,
theirs by checker and level (1 error, 2 warning, 3 info) and which checkers it skipped. The peer is
benchmarks/peers/asam_qc.py, shared with the slow tests (tests/test_oracles.py).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from peers import PeerUnavailable, asam_qc  # benchmarks/peers: the oracles shared with the slow tests

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
SHARED = REPO.parent / "shared" / "data"
TARGET_S = 2.0

OURS = r"""
import json, sys, time
t0 = time.perf_counter()
from tavf_mapkit.validate import validate_file
t1, c1 = time.perf_counter(), time.process_time()
report = validate_file(sys.argv[1])
t2, c2 = time.perf_counter(), time.process_time()
s = report.summary
print(json.dumps({"import": t1 - t0, "validate": t2 - t1, "cpu": c2 - c1, "errors": s["errors"], "warnings": s["warnings"],
                  "info": s["info"], "by_rule": s["by_rule"]}))
"""

def run_ours(path: Path) -> dict:
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-c", OURS, str(path)], capture_output=True, text=True, timeout=900,
                          check=False)
    wall = time.perf_counter() - start
    if done.returncode != 0 or not done.stdout.strip():
        return {"error": (done.stderr.strip().splitlines() or ["failed"])[-1][:200]}
    return {**json.loads(done.stdout.strip().splitlines()[-1]), "process": wall}


def tavf_xodr(folder: Path) -> Path:
    from tavf_mapkit.netconvert import find_netconvert

    out = folder / "tavf.xodr"
    subprocess.run([str(find_netconvert()), "-s", str(SHARED / "hamburg" / "tavf_dlr_sumo_net" / "network.net.xml.gz"),
                    "--opendrive-output", str(out)], check=True, capture_output=True)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--no-peers", action="store_true")
    args = parser.parse_args()
    program = None
    if not args.no_peers:
        try:
            program = asam_qc.program(install=True)
        except PeerUnavailable as error:
            print(f"  {error}", file=sys.stderr)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        files = {"TAVF (netconvert)": tavf_xodr(folder), "Town07": SHARED / "xodr" / "libopendrive" / "test.xodr"}
        jungfernstieg = REPO / "build" / "jungfernstieg" / "jungfernstieg.xodr"
        if jungfernstieg.exists():
            files["Jungfernstieg build"] = jungfernstieg
        rows = []
        for label, path in files.items():
            ours = [run_ours(path) for _ in range(args.repeat)]
            good = [r for r in ours if "error" not in r]
            row = {"file": label, "size_mb": path.stat().st_size / 1e6,
                   "ours": {**good[0], "validate": statistics.median(r["validate"] for r in good),
                            "process": statistics.median(r["process"] for r in good),
                            "cpu": statistics.median(r["cpu"] for r in good)} if good else ours[0]}
            if program is not None:
                row["qc"] = asam_qc.check(path, folder, program)
            rows.append(row)
    for row in rows:
        ours, qc = row["ours"], row.get("qc")
        print(f"\n== {row['file']} ({row['size_mb']:.1f} MB)")
        if "error" in ours:
            print(f"  mapkit validate FAILED: {ours['error']}")
        else:
            print(f"  mapkit validate   {ours['validate']:.2f} s in process ({ours['cpu']:.2f} s CPU), "
                  f"{ours['process']:.2f} s as a process; "
                  f"{ours['errors']} errors, {ours['warnings']} warnings, {ours['info']} info")
            for rule, count in ours["by_rule"].items():
                print(f"      {count:>5}  {rule}")
        if qc is None:
            continue
        if "error" in qc:
            print(f"  asam-qc-opendrive FAILED after {qc['process']:.2f} s: {qc['error']}")
            continue
        ratio = qc["process"] / ours["process"] if "process" in ours else float("nan")
        levels = ", ".join(f"{n} {level}" for level, n in sorted(qc["levels"].items())) or "no issues"
        print(f"  asam-qc-opendrive {qc['process']:.2f} s as a process ({ratio:.1f}x ours); {levels}; "
              f"{len(qc['skipped'])} of {len(asam_qc.CHECKERS)} checkers skipped (failed preconditions)")
        for name, count in sorted(qc["issues"].items()):
            print(f"      {count:>5}  {name}")
    tavf = rows[0]["ours"]
    if "validate" in tavf:
        print(f"\nTAVF target: validate {tavf['validate']:.2f} s / {TARGET_S:.0f} s = {tavf['validate'] / TARGET_S:.2f} "
              f"(CPU {tavf['cpu']:.2f} s; load average now {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores)")


if __name__ == "__main__":
    main()
