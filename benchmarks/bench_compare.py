"""mapkit compare and match-trace on the TAVF OpenDRIVE, with a peer for the Hausdorff part, same run.

    $ .venv/bin/python benchmarks/bench_compare.py [--repeat 3]

TAVF OpenDRIVE: netconvert's OpenDRIVE of DLR's TAVF network (made here with the eclipse-sumo wheel).
Measured (median wall of --repeat runs, each in a fresh subprocess with its peak RSS):
- compare against DLR's SUMO network (the issue's case; target <= 5 s) and against itself;
- match-trace of the shared GNSS ride (587 fixes) including the lane graph;
- peer: shapely.hausdorff_distance (GEOS) between the driving lane centre lines within 400 m of the centre
  and a shifted copy, against our exact point-to-segment Hausdorff on the same samples (GEOS is O(n m)).
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
SHARED = REPO.parent / "shared" / "data"
TARGET_COMPARE_S = 5.0

COMPARE = r"""
import json, resource, sys, time
t0 = time.perf_counter()
from tavf_mapkit.accuracy.compare import compare_networks
t1 = time.perf_counter()
report = compare_networks(sys.argv[1], sys.argv[2]).to_dict()
t2 = time.perf_counter()
print(json.dumps({"wall": t2 - t1, "import": t1 - t0, "median_m": report["offset"]["median_m"],
                  "hausdorff_m": report["hausdorff_m"]["lanes"],
                  "rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""

MATCH = r"""
import json, resource, sys, time
from tavf_mapkit.accuracy.matching import match_trace
from tavf_mapkit.opendrive import load_opendrive
from tavf_mapkit.traces import read_trace
odr = load_opendrive(sys.argv[1])
trace = read_trace(sys.argv[2])
t1 = time.perf_counter()
stats = match_trace(odr, trace).stats()
t2 = time.perf_counter()
print(json.dumps({"wall": t2 - t1, "median_m": stats["median_m"], "fixes": stats["fixes"],
                  "rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""

HAUSDORFF = r"""
import json, sys, time
import numpy as np
import shapely
from tavf_mapkit.accuracy.networks import CommonFrame, load_opendrive_network
def frame_for(lon, lat):
    return CommonFrame(0.5 * (lon.min() + lon.max()), 0.5 * (lat.min() + lat.max()))
network, _ = load_opendrive_network(sys.argv[1], frame_for)
lanes = network.lanes
# GEOS's Hausdorff compares every vertex with every vertex: keep it to the lanes within 400 m of the centre
near = (lanes.lane_type == "driving") & (np.hypot(lanes.x, lanes.y) < 400.0)
a = lanes.subset(near)
dx, dy = 0.7, -0.3
t1 = time.perf_counter()
ours = max(a.distance_from(a.x + dx, a.y + dy).max(), a.distance_from(a.x - dx, a.y - dy).max())
t2 = time.perf_counter()
lines = [shapely.LineString(np.column_stack([a.x[a.line == k], a.y[a.line == k]]))
         for k in np.unique(a.line) if (a.line == k).sum() >= 2]
one = shapely.MultiLineString(lines)
two = shapely.affinity.translate(one, dx, dy)
t3 = time.perf_counter()
geos = shapely.hausdorff_distance(one, two)
t4 = time.perf_counter()
print(json.dumps({"ours_s": t2 - t1, "geos_s": t4 - t3, "ours_m": float(ours), "geos_m": float(geos),
                  "points": int(len(a.x))}))
"""


def run(script: str, *args: str) -> dict:
    result = subprocess.run([sys.executable, "-c", script, *args], capture_output=True, text=True, check=False)
    if result.returncode != 0:
        return {"error": result.stderr.strip().splitlines()[-1] if result.stderr.strip() else "failed"}
    return json.loads(result.stdout.strip().splitlines()[-1])


def median_of(script: str, args: list[str], repeat: int) -> dict:
    runs = [run(script, *args) for _ in range(repeat)]
    good = [r for r in runs if "error" not in r]
    if not good:
        return runs[0]
    out = dict(good[0])
    out["wall"] = statistics.median(r["wall"] for r in good)
    out["rss_mb"] = max(r["rss_mb"] for r in good)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeat", type=int, default=3)
    options = parser.parse_args()
    sys.path.insert(0, str(REPO / "tests"))
    from conftest import netconvert_binary

    net = SHARED / "hamburg" / "tavf_dlr_sumo_net" / "network.net.xml.gz"
    ride = SHARED / "hamburg" / "gnss_ride_b4" / "thomas.json"
    with tempfile.TemporaryDirectory() as folder:
        xodr = Path(folder) / "tavf.xodr"
        subprocess.run([netconvert_binary(), "-s", str(net), "--opendrive-output", str(xodr)], check=True,
                       capture_output=True)
        vs_sumo = median_of(COMPARE, [str(xodr), str(net)], options.repeat)
        vs_self = median_of(COMPARE, [str(xodr), str(xodr)], options.repeat)
        match = median_of(MATCH, [str(xodr), str(ride)], options.repeat)
        hausdorff = run(HAUSDORFF, str(xodr))
    print(f"TAVF OpenDRIVE (netconvert of DLR's net), {options.repeat} runs, median wall time")
    print(f"  compare vs DLR SUMO net   {vs_sumo.get('wall', float('nan')):6.2f} s  (target <= {TARGET_COMPARE_S:g} s, "
          f"ratio {vs_sumo.get('wall', float('nan')) / TARGET_COMPARE_S:.2f}; peak {vs_sumo.get('rss_mb', 0):.0f} MB; "
          f"median offset {vs_sumo.get('median_m')} m)")
    print(f"  compare vs itself         {vs_self.get('wall', float('nan')):6.2f} s  (two OpenDRIVE loads; "
          f"peak {vs_self.get('rss_mb', 0):.0f} MB)")
    print(f"  match-trace, 587 fixes    {match.get('wall', float('nan')):6.2f} s  (lane graph + HMM; median "
          f"{match.get('median_m')} m)")
    if "error" in hausdorff:
        print(f"  Hausdorff peer failed: {hausdorff['error']}")
    else:
        print(f"  Hausdorff, {hausdorff['points']} lane samples vs a (0.7, -0.3) m shifted copy: ours "
              f"{hausdorff['ours_s']:.3f} s = {hausdorff['ours_m']:.3f} m (exact, point to segment), GEOS (shapely) "
              f"{hausdorff['geos_s']:.3f} s = {hausdorff['geos_m']:.3f} m (vertex based); time ratio GEOS/ours "
              f"{hausdorff['geos_s'] / max(hausdorff['ours_s'], 1e-9):.1f}")


if __name__ == "__main__":
    main()
