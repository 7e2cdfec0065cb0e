"""Dask on this machine: speed-up of the tile stages and of a 16-run sweep with 1 and 2 workers, the per-task
overhead, and an Amdahl projection for 16 and 64 workers from measured task times.

    $ .venv/bin/python benchmarks/bench_distributed.py                                   # Krems + Perth sweep
    $ .venv/bin/python benchmarks/bench_distributed.py --map ../shared/data/zoo/osm/SI_maribor.osm.gz --runs 0
    $ .venv/bin/python benchmarks/bench_distributed.py --json benchmarks/results/distributed.json

1. ``mapkit build MAP`` once, in one process (``--json``: seconds per stage). Its OpenDRIVE and OSM copy then
   feed the tile stages (load the map, mesh, collision world) three times: in this process without Dask, on a
   LocalCluster of 1 worker and of 2 workers (processes, 1 thread each; the cluster's start-up is not counted,
   the workers get the client's loaded map pickled, as a real build's do). The three results must be
   byte-identical. CPU seconds of each process are printed too (the client's include the LocalCluster's
   scheduler): on a shared machine they say more than the wall clock.
2. Per-task overhead: 400 empty tasks through ``cluster.Fanout.map`` on 2 workers.
3. ``twin sweep`` of ``--runs`` seeds on the sweep map (default the zoo's Perth roundabout): one after another
   without Dask, then ``--workers 2`` (LocalCluster start-up included: a user pays it).
4. Amdahl: the tasks' compute times (Dask's task stream of the 1-worker run) are the parallel part, per kind of
   task; everything else of the serial build is the serial part, named stage by stage. Projected build time on
   n workers = serial + sum over kinds of max(work / n, longest task) + tasks x overhead / n.
The machine has 2 cores and is shared: the load average is printed before and after; compare within one run.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("TAVF_SHARED_DATA", REPO.parent / "shared" / "data"))
BIN = Path(sys.executable).parent
DEFAULT_MAP = SHARED / "zoo" / "osm" / "AT_krems.osm.gz"
SWEEP_MAP = SHARED / "zoo" / "osm" / "AU_perth_peanut_roundabout_LHT.osm.gz"
TARGET_SPEEDUP = 1.7


def load() -> str:
    return " ".join(Path("/proc/loadavg").read_text().split()[:3])


def serial_build(source: Path, out: Path) -> dict:
    started = time.perf_counter()
    done = subprocess.run([str(BIN / "mapkit"), "build", str(source), "-o", str(out), "-q", "--json"],
                          capture_output=True, text=True, check=True)
    wall = time.perf_counter() - started
    result = json.loads(done.stdout)
    return {"wall_s": wall, "stages": {s["name"]: s["seconds"] or 0.0 for s in result["stages"]}}


def folder_digest(folder: Path) -> str:
    digest = hashlib.sha256()
    for path in sorted(folder.rglob("*")):
        if path.is_file():
            digest.update(path.relative_to(folder).as_posix().encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()


def cpu_seconds() -> float:
    """User + system CPU seconds of this process so far."""
    import resource

    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def tile_stages(build: Path, out: Path, fanout=None) -> dict:
    """Load the build's map, mesh it and make the collision world into ``out``; seconds of each, and CPU
    seconds of this process and of each worker."""
    from tavf_mapkit.mesh.folder import write_mesh_folder
    from tavf_mapkit.opendrive import load_opendrive
    from tavf_mapkit.world.build import build_collision_world_from_tiles

    xodr = next(build.glob("*.xodr"))
    osm = build / "source" / f"{build.name}.osm"
    workers_before = {} if fanout is None else fanout.client.run(cpu_seconds)
    cpu_before = cpu_seconds()
    started = time.perf_counter()
    odr = load_opendrive(xodr)  # the workers get this map, pickled, once the mesher has cut its units
    loaded = time.perf_counter()
    write_mesh_folder(odr, out / "mesh", osm_path=osm if osm.is_file() else None, fanout=fanout)
    meshed = time.perf_counter()
    build_collision_world_from_tiles(out / "mesh" / "labelled", out, fanout=fanout)
    done = time.perf_counter()
    client_cpu = cpu_seconds() - cpu_before
    workers_after = {} if fanout is None else fanout.client.run(cpu_seconds)
    return {"load_s": loaded - started, "mesh_s": meshed - loaded, "collision_s": done - meshed,
            "total_s": done - started, "client_cpu_s": client_cpu,
            "workers_cpu_s": [workers_after[w] - workers_before[w] for w in sorted(workers_after)],
            "digest": folder_digest(out)}


# the functions whose work a cluster runs as tasks, by the kind of task that does it: a batch of roads, the
# junction curbs, one final tile's merge + files + paint, one collision tile's bodies
PASSES = {("tavf_mapkit.mesh.tiled", "_mesh_batch"): "batch_task",
          ("tavf_mapkit.mesh.tiled", "_junction_curbs"): "curb_task",
          ("tavf_mapkit.mesh.tiled", "tile_product"): "tiles_task",
          ("tavf_mapkit.world.build", "tile_files"): "collision_task"}


def timed_passes(work) -> tuple:
    """``work()`` in this process with the seconds spent in each function a cluster would run as tasks
    (wrapped with timers for the run): (result, {task kind: seconds})."""
    import importlib

    seconds = defaultdict(float)
    originals = {key: getattr(importlib.import_module(key[0]), key[1]) for key in PASSES}

    def timed(key):
        def run(*args, **kwargs):
            started = time.perf_counter()
            try:
                return originals[key](*args, **kwargs)
            finally:
                seconds[PASSES[key]] += time.perf_counter() - started
        return run

    try:
        for key in PASSES:
            setattr(importlib.import_module(key[0]), key[1], timed(key))
        result = work()
    finally:
        for key, function in originals.items():
            setattr(importlib.import_module(key[0]), key[1], function)
    return result, dict(seconds)


def on_cluster(workers: int, work):
    """``work(fanout, client)`` on a fresh LocalCluster of ``workers`` processes; its start-up is not timed."""
    from tavf_mapkit.cluster import connect

    with connect(workers=workers) as fanout:
        return work(fanout, fanout.client)


def task_kinds(stream: list[dict]) -> dict:
    """Compute seconds per kind of task (its function) from Dask's task stream."""
    from distributed.utils import key_split

    kinds = defaultdict(list)
    for record in stream:
        kind = key_split(record["key"])
        for part in record.get("startstops", ()):
            if part["action"] == "compute":
                kinds[kind].append(part["stop"] - part["start"])
    return {kind: {"tasks": len(times), "work_s": sum(times), "longest_s": max(times)}
            for kind, times in kinds.items()}


def empty_task():
    return None


def overhead(fanout, client, count: int = 400) -> float:
    list(fanout.map(empty_task, [()] * 20))  # warm: functions shipped, connections open
    started = time.perf_counter()
    list(fanout.map(empty_task, [()] * count))
    return (time.perf_counter() - started) / count


def sweep(build: Path, runs: int, out: Path, workers: int | None) -> float:
    command = [str(BIN / "twin"), "sweep", "--map", str(build), "--seeds", f"0-{runs - 1}", "--duration", "30",
               "-o", str(out), "-q"]
    if workers:
        command += ["--workers", str(workers)]
    started = time.perf_counter()
    subprocess.run(command, check=True, capture_output=True)
    return time.perf_counter() - started


def amdahl(serial: dict, kinds: dict, in_process: dict, task_overhead: float, workers: list[int]) -> dict:
    """The parallel part: each kind of task's work as it took in one process (``in_process``: seconds of the
    passes, and of the collision stage), its longest task scaled by the same in-process / worker ratio. The
    workers' unpickling of the client's map (``preload_task``, ``mesh.remote.share_map``) runs while the client
    plans the first batches; it is left out."""
    preload = kinds.get("preload_task", {"work_s": 0.0, "tasks": 0})
    kinds = {name: dict(kind, worker_s=kind["work_s"]) for name, kind in kinds.items() if name != "preload_task"}
    for name, kind in kinds.items():
        own = in_process.get(name)
        if own is not None and kind["work_s"] > 0:
            kind["longest_s"] *= own / kind["work_s"]
            kind["work_s"] = own
    work = sum(kind["work_s"] for kind in kinds.values())
    tasks = sum(kind["tasks"] for kind in kinds.values())
    total = serial["wall_s"]
    stages = serial["stages"]
    tile = stages.get("mesh", 0.0) + stages.get("collision", 0.0)
    serial_parts = {name: seconds for name, seconds in stages.items() if name not in ("mesh", "collision")}
    serial_parts["mesh + collision in the client (map load, units, buildings, writing files)"] = max(0.0,
                                                                                                      tile - work)
    serial_parts["process start-up and manifest"] = max(0.0, total - sum(stages.values()))
    serial_parts[f"(workers unpickle the map meanwhile: {preload['work_s']:.1f} s in all)"] = 0.0
    total_serial = total - work
    serial_s = total_serial
    out = {"serial_s": serial_s, "parallel_s": work, "tasks": tasks, "serial_parts": serial_parts,
           "projection": {}}
    for n in workers:
        t = serial_s + sum(max(kind["work_s"] / n, kind["longest_s"]) for kind in kinds.values())
        t += tasks * task_overhead / n
        out["projection"][n] = {"seconds": t, "speedup": total / t}
    out["limit_speedup"] = total / serial_s if serial_s > 0 else None
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--map", type=Path, default=DEFAULT_MAP, help="input of the tile-stage figures")
    parser.add_argument("--sweep-map", type=Path, default=SWEEP_MAP)
    parser.add_argument("--runs", type=int, default=16, help="runs of the sweep (0: no sweep)")
    parser.add_argument("--json", type=Path, help="write the figures here too")
    parser.add_argument("--projection-only", action="store_true",
                        help="only the serial build and the 1-worker run the projection needs (large maps)")
    args = parser.parse_args()
    from distributed import get_task_stream

    figures = {"load_before": load(), "cpus": os.cpu_count()}
    print(f"load average before: {figures['load_before']}  ({os.cpu_count()} CPUs, shared)")
    with tempfile.TemporaryDirectory(prefix="bench-distributed-") as scratch:
        scratch = Path(scratch)
        build = scratch / "serial" / args.map.name.split(".")[0]
        serial = serial_build(args.map, build)
        figures["serial_build"] = serial
        print(f"\nmapkit build {args.map.name}, one process: {serial['wall_s']:.1f} s  "
              + "  ".join(f"{k} {v:.1f}" for k, v in serial["stages"].items()))

        local, passes = timed_passes(lambda: tile_stages(build, scratch / "t0"))
        figures["in_process_passes_s"] = passes
        one = on_cluster(1, lambda fanout, client: _streamed(get_task_stream, client,
                                                             lambda: tile_stages(build, scratch / "t1", fanout)))
        if not args.projection_only:
            two = on_cluster(2, lambda fanout, client: tile_stages(build, scratch / "t2", fanout))
            same = local["digest"] == one[0]["digest"] == two["digest"]
            figures["tile_stages"] = {"no_dask": local, "workers_1": one[0], "workers_2": two, "identical": same}
            print("\ntile stages (load + mesh + collision)      total    load    mesh  collision  speed-up"
                  "   CPU s: client  workers")
            for label, t in (("this process, no Dask", local), ("LocalCluster, 1 worker", one[0]),
                             ("LocalCluster, 2 workers", two)):
                print(f"  {label:<40} {t['total_s']:6.1f}  {t['load_s']:6.1f}  {t['mesh_s']:6.1f}  "
                      f"{t['collision_s']:8.1f}  {local['total_s'] / t['total_s']:6.2f}x  "
                      f"{t['client_cpu_s']:13.1f}  {' + '.join(f'{w:.1f}' for w in t['workers_cpu_s']) or '-'}")
            print(f"  2 workers vs 1 worker: {one[0]['total_s'] / two['total_s']:.2f}x (target {TARGET_SPEEDUP}x); "
                  f"files identical in all three: {same}")

        per_task = on_cluster(2, overhead)
        figures["task_overhead_s"] = per_task
        print(f"\nper-task overhead (empty task, 2 workers, ordered map): {per_task * 1000:.2f} ms")

        kinds = task_kinds(one[1])
        figures["tasks"] = kinds
        print("\ntasks of the 1-worker run           count  worker s  longest s  in one process s")
        for kind, k in sorted(kinds.items()):
            own = passes.get(kind)
            print(f"  {kind:<32} {k['tasks']:6d}  {k['work_s']:8.2f}  {k['longest_s']:9.3f}  "
                  + (f"{own:16.2f}" if own is not None else f"{'-':>16}"))
        projection = amdahl(serial, kinds, passes, per_task, [1, 2, 16, 64])
        figures["amdahl"] = projection
        print(f"\nAmdahl for {args.map.name}: serial {projection['serial_s']:.1f} s of {serial['wall_s']:.1f} s, "
              f"parallel {projection['parallel_s']:.1f} s in {projection['tasks']} tasks")
        for name, seconds in sorted(projection["serial_parts"].items(), key=lambda item: -item[1]):
            print(f"  serial: {name:<72} {seconds:6.1f} s")
        for n, p in projection["projection"].items():
            print(f"  {n:3d} workers: {p['seconds']:6.1f} s  ({p['speedup']:.2f}x the one-process build)")
        if projection["limit_speedup"]:
            print(f"  limit (infinitely many workers): {projection['limit_speedup']:.2f}x")

        if args.runs:
            sweep_build = scratch / "sweep-map" / "perth"
            serial_build(args.sweep_map, sweep_build)
            alone = sweep(sweep_build, args.runs, scratch / "sweep-1", None)
            pair = sweep(sweep_build, args.runs, scratch / "sweep-2", 2)
            figures["sweep"] = {"runs": args.runs, "workers_1_s": alone, "workers_2_s": pair}
            print(f"\ntwin sweep of {args.runs} runs (30 s each, {args.sweep_map.name}): one after another "
                  f"{alone:.1f} s, 2 workers {pair:.1f} s -> {alone / pair:.2f}x (target {TARGET_SPEEDUP}x)")
    figures["load_after"] = load()
    print(f"\nload average after: {figures['load_after']}")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(figures, indent=1, default=str) + "\n")
    return 0


def _streamed(get_task_stream, client, work):
    with get_task_stream(client) as stream:
        result = work()
    return result, stream.data


if __name__ == "__main__":
    sys.exit(main())
