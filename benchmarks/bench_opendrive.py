"""Load + evaluate every lane border at 0.5 m: tavf-mapkit vs the C++ evaluator and the PyPI reader pyxodr.

    $ .venv/bin/python benchmarks/bench_opendrive.py [--repeat 5] [--no-peers]

Files: netconvert's OpenDRIVE of DLR's TAVF network (made here with the eclipse-sumo wheel) and CARLA's Town07.
Each measurement runs in a fresh subprocess so peak RSS (ru_maxrss) belongs to that job alone; wall time is the
median of --repeat runs. pyxodr lives in its own venv (benchmarks/.peers/pyxodr, created on first use).
Targets (TAVF): <= 0.5 s wall, <= 300 MB peak RSS, and (issue 15) within 3x the C++ evaluator's time for the
same job: ../shared/tools/libopendrive's dump_borders (libOpenDRIVE: parse, every lane border at 0.5 m, written
as text; built by ``python -m benchmarks.peers.install``), timed in the same run (median of --repeat).
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import venv
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
SHARED = REPO.parent / "shared" / "data"
PEERS = HERE / ".peers"
sys.path.insert(0, str(HERE))  # benchmarks/peers

OURS = r"""
import json, resource, sys, time
t0 = time.perf_counter()
from tavf_mapkit.opendrive import load_opendrive
from tavf_mapkit.opendrive.sampling import sample_lane_borders
t1 = time.perf_counter()
odr = load_opendrive(sys.argv[1])
t2 = time.perf_counter()
borders = sample_lane_borders(odr, 0.5)
t3 = time.perf_counter()
print(json.dumps({"import": t1 - t0, "load": t2 - t1, "evaluate": t3 - t2, "wall": t3 - t1,
                  "points": int(len(borders.x)), "rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""

PYXODR = r"""
import json, resource, sys, time
t0 = time.perf_counter()
from pyxodr.road_objects.network import RoadNetwork
t1 = time.perf_counter()
try:
    network = RoadNetwork(sys.argv[1], resolution=0.5)
    points = 0
    for road in network.get_roads():
        for section in road.lane_sections:
            for lane in list(section.left_lanes) + list(section.right_lanes):
                points += len(lane.boundary_line)
    t2 = time.perf_counter()
    print(json.dumps({"wall": t2 - t1, "points": points,
                      "rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
except Exception as error:
    print(json.dumps({"error": f"{type(error).__name__}: {error}"[:200],
                      "rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def run(python: str, script: str, path: Path) -> dict:
    done = subprocess.run([python, "-c", script, str(path)], capture_output=True, text=True, timeout=900)
    if done.returncode != 0 or not done.stdout.strip():
        return {"error": (done.stderr.strip().splitlines() or ["failed"])[-1][:200]}
    return json.loads(done.stdout.strip().splitlines()[-1])


def peer_python(name: str, package: str) -> str | None:
    folder = PEERS / name
    python = folder / "bin" / "python"
    if not python.exists():
        print(f"creating {folder} with {package} ...", file=sys.stderr)
        venv.create(folder, with_pip=True)
        done = subprocess.run([str(python), "-m", "pip", "install", "-q", package], capture_output=True, text=True)
        if done.returncode != 0:
            print(f"  could not install {package}: {done.stderr.strip()[-200:]}", file=sys.stderr)
            return None
    return str(python)


def tavf_xodr(folder: Path) -> Path:
    from tavf_mapkit.netconvert import find_netconvert

    out = folder / "tavf.xodr"
    subprocess.run([str(find_netconvert()), "-s", str(SHARED / "hamburg" / "tavf_dlr_sumo_net" / "network.net.xml.gz"),
                    "--opendrive-output", str(out)], check=True, capture_output=True)
    return out


def cpp_dump(path: Path, repeat: int) -> dict:
    """libOpenDRIVE's parse + every lane border at 0.5 m + text out (to /dev/null), median wall of ``repeat``."""
    import time

    from peers import PeerUnavailable
    from peers.libopendrive import binary

    try:
        program = binary()
    except PeerUnavailable as error:  # not built here: say so in the table
        return {"error": f"{type(error).__name__}: {error}"[:200]}
    walls = []
    for _ in range(repeat):
        started = time.perf_counter()
        done = subprocess.run([str(program), str(path), "0.5"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                              timeout=900, check=False)
        walls.append(time.perf_counter() - started)
        if done.returncode != 0:
            return {"error": (done.stderr.decode(errors="replace").strip().splitlines() or ["failed"])[-1][:200]}
    return {"wall": statistics.median(walls)}


def median_of(results: list[dict], key: str) -> float | None:
    values = [r[key] for r in results if key in r]
    return statistics.median(values) if values else None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--no-peers", action="store_true")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        files = {"TAVF (netconvert)": tavf_xodr(Path(tmp)),
                 "Town07": SHARED / "xodr" / "libopendrive" / "test.xodr"}
        rows = []
        for label, path in files.items():
            ours = [run(sys.executable, OURS, path) for _ in range(args.repeat)]
            wall, rss = median_of(ours, "wall"), max(r.get("rss_mb", 0) for r in ours)
            row = {"file": label, "size_mb": path.stat().st_size / 1e6, "ours_wall_s": wall,
                   "ours_load_s": median_of(ours, "load"), "ours_eval_s": median_of(ours, "evaluate"),
                   "ours_rss_mb": rss, "ours_points": ours[0].get("points")}
            row["cpp"] = cpp_dump(path, args.repeat)
            if not args.no_peers:
                python = peer_python("pyxodr", "pyxodr")
                peer = run(python, PYXODR, path) if python else {"error": "not installed"}
                row["pyxodr"] = peer
            rows.append(row)
    print(f"{'file':<20} {'MB':>5} {'ours s':>8} {'load':>6} {'eval':>6} {'RSS MB':>7} {'points':>8} "
          f"{'C++ s':>6} {'/C++':>5}   pyxodr")
    for row in rows:
        cpp = row["cpp"].get("wall")
        cpp_text = f"{cpp:>6.3f} {row['ours_wall_s'] / cpp:>4.1f}x" if cpp else f"{'-':>6} {'-':>5}"
        peer = row.get("pyxodr", {})
        if "error" in peer:
            peer_text = f"FAILED: {peer['error']}"
        elif peer:
            ratio = peer["wall"] / row["ours_wall_s"]
            peer_text = f"{peer['wall']:.2f} s, {peer['rss_mb']:.0f} MB, {peer['points']} pts ({ratio:.1f}x slower)"
        else:
            peer_text = "-"
        print(f"{row['file']:<20} {row['size_mb']:>5.1f} {row['ours_wall_s']:>8.3f} {row['ours_load_s']:>6.3f} "
              f"{row['ours_eval_s']:>6.3f} {row['ours_rss_mb']:>7.0f} {row['ours_points']:>8} {cpp_text}   {peer_text}")
    tavf = rows[0]
    print(f"\nTAVF targets: wall {tavf['ours_wall_s']:.3f} s / 0.5 s = {tavf['ours_wall_s'] / 0.5:.2f}; "
          f"peak RSS {tavf['ours_rss_mb']:.0f} MB / 300 MB = {tavf['ours_rss_mb'] / 300:.2f}; "
          + (f"vs the C++ evaluator in this run {tavf['ours_wall_s'] / tavf['cpp']['wall']:.2f}x (target 3x)"
             if "wall" in tavf["cpp"] else f"C++ evaluator: {tavf['cpp'].get('error')}"))


if __name__ == "__main__":
    main()
