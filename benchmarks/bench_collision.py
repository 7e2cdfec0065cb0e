"""Collision world of netconvert's OpenDRIVE of DLR's TAVF network: build, load into pybullet, ray cost.

    $ .venv/bin/python benchmarks/bench_collision.py [--repeat 3]

Per eps (0.1 and 0.05), in a fresh subprocess each (so peak RSS belongs to that job alone; wall = median):
- build: ``road_surface`` + scene solids + tiling + OBJ/world.json writing (``build_collision_world``), and the
  part after the road surface alone (what the collision stage adds to the mesh stage's work);
- load: ``tavf_mapkit.world.load`` into pybullet DIRECT (every tile OBJ -> static concave triangle mesh);
- rays: downward rays at every driving-lane centre sample (0.5 m), share within 5 cm of the OpenDRIVE height.
Peer in the same run: the same surface as ONE OBJ body (what an untiled world costs to load; it would not fit
pybullet's 131,072-vertex in-memory limit). Targets (issue 4, eps 0.1): mesh + export + collision <= 3 s,
peak <= 1 GB; the collision part is reported here, the mesh part by bench_mesh.py.
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

JOB = r"""
import json, resource, sys, time
from pathlib import Path
t0 = time.perf_counter()
import numpy as np, pybullet
from tavf_mapkit.opendrive import load_opendrive
from tavf_mapkit.opendrive.sampling import sample_lanes
from tavf_mapkit.mesh import road_surface
from tavf_mapkit.world import build_collision_world, load
from tavf_mapkit.world.objfile import obj_text
t1 = time.perf_counter()
xodr, eps, out = sys.argv[1], float(sys.argv[2]), Path(sys.argv[3])
odr = load_opendrive(xodr)
t2 = time.perf_counter()
surface = road_surface(odr, eps)
t3 = time.perf_counter()
world = build_collision_world(odr, out, eps=eps, surface=surface)
t4 = time.perf_counter()
build_rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
cid = pybullet.connect(pybullet.DIRECT)
t5 = time.perf_counter()
bodies = load(out, cid)
t6 = time.perf_counter()
sampling = sample_lanes(odr, 0.5)
centres = sampling.center_points()[sampling.lane_type == "driving"]
t7 = time.perf_counter()
z, _ = bodies.cast_down(centres)
t8 = time.perf_counter()
ok = float(np.mean(np.abs(z - centres[:, 2]) <= 0.05))
single = out / "single.obj"
single.write_text(obj_text("all", surface.vertices - bodies.origin, surface.faces))
cid2 = pybullet.connect(pybullet.DIRECT)
t9 = time.perf_counter()
shape = pybullet.createCollisionShape(pybullet.GEOM_MESH, fileName=str(single),
                                      flags=pybullet.GEOM_FORCE_CONCAVE_TRIMESH, physicsClientId=cid2)
pybullet.createMultiBody(0, shape, physicsClientId=cid2)
t10 = time.perf_counter()
size = sum(p.stat().st_size for p in (out / "collision").rglob("*") if p.is_file())
print(json.dumps({"import": t1 - t0, "read_xodr": t2 - t1, "surface": t3 - t2, "collision": t4 - t3,
                  "build": t4 - t2, "load": t6 - t5, "rays": t8 - t7, "n_rays": len(centres), "hit_5cm": ok,
                  "single_obj_load": t10 - t9, "build_rss_mb": build_rss, "files_mb": size / 1e6,
                  "rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, **world["totals"]}))
"""


def run(path: Path, eps: float) -> dict:
    with tempfile.TemporaryDirectory() as out:
        done = subprocess.run([sys.executable, "-c", JOB, str(path), str(eps), out], capture_output=True, text=True,
                              timeout=900, check=False)
    if done.returncode != 0 or not done.stdout.strip():
        return {"error": (done.stderr.strip().splitlines() or ["failed"])[-1][:300]}
    return json.loads(done.stdout.strip().splitlines()[-1])


def tavf_xodr(folder: Path) -> Path:
    from tavf_mapkit.netconvert import find_netconvert

    out = folder / "tavf.xodr"
    subprocess.run([str(find_netconvert()), "-s", str(SHARED / "hamburg" / "tavf_dlr_sumo_net" / "network.net.xml.gz"),
                    "--opendrive-output", str(out)], check=True, capture_output=True)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        xodr = tavf_xodr(Path(tmp))
        for eps in (0.1, 0.05):
            results = [run(xodr, eps) for _ in range(args.repeat)]
            good = [r for r in results if "error" not in r]
            if not good:
                print(f"eps {eps}: {results[0]['error']}")
                continue
            row = {key: statistics.median(r[key] for r in good) for key in good[0] if key != "hit_5cm"}
            row["hit_5cm"] = min(r["hit_5cm"] for r in good)
            row["rss_mb"] = max(r["rss_mb"] for r in good)
            row["build_rss_mb"] = max(r["build_rss_mb"] for r in good)
            row["eps"] = eps
            rows.append(row)
    print("TAVF (netconvert OpenDRIVE of DLR's SUMO network), median of", args.repeat, "runs")
    print(f"{'eps':>5} {'surface s':>9} {'+collision s':>12} {'load s':>7} {'1-OBJ load':>10} {'tiles':>6} "
          f"{'bodies':>6} {'triangles':>9} {'MB':>5} {'build RSS':>9} {'rays':>7} {'ray s':>6} {'hit<=5cm':>8}")
    for r in rows:
        print(f"{r['eps']:>5} {r['surface']:>9.3f} {r['collision']:>12.3f} {r['load']:>7.3f} "
              f"{r['single_obj_load']:>10.3f} {r['tiles']:>6.0f} {r['bodies']:>6.0f} {r['triangles']:>9.0f} "
              f"{r['files_mb']:>5.1f} {r['build_rss_mb']:>8.0f}M {r['n_rays']:>7.0f} {r['rays']:>6.2f} "
              f"{100 * r['hit_5cm']:>7.3f}%")
    for r in rows:
        if r["eps"] == 0.1:
            print(f"\neps 0.1: collision part {r['collision']:.2f} s after the surface "
                  f"({r['collision'] / 3.0:.0%} of the 3 s budget for mesh + export + collision); "
                  f"surface + collision {r['build']:.2f} s; build peak RSS {r['build_rss_mb']:.0f} MB "
                  f"({r['build_rss_mb'] / 1024:.0%} of 1 GB); tiled load {r['load']:.2f} s vs one OBJ "
                  f"{r['single_obj_load']:.2f} s ({r['load'] / max(r['single_obj_load'], 1e-9):.2f}x)")


if __name__ == "__main__":
    main()
