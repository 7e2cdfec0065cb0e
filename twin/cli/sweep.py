"""``twin sweep``: seeded ``twin drive`` runs of one build, here or on a Dask cluster, gathered into one table."""

from __future__ import annotations

import json
import time
from contextlib import ExitStack
from pathlib import Path

import click

from tavf_mapkit.cli.options import verbosity
from tavf_mapkit.cluster import check_cluster_options, wants_cluster
from tavf_mapkit.errors import StageError


@click.command(context_settings={"help_option_names": ["-h", "--help"]})
@click.option("--map", "map_dir", required=True, type=click.Path(path_type=Path), metavar="BUILD",
              help="A build folder made by `mapkit build`.")
@click.option("--seeds", required=True, metavar="A-B[,C,...]", help="Seeds, one run each: 0-199, or 1,5,9-12.")
@click.option("--duration", type=click.FloatRange(min=0, min_open=True), default=60.0, show_default=True,
              metavar="S", help="Simulated seconds per run (random routes).")
@click.option("--traffic", type=click.IntRange(min=0), default=0, show_default=True, metavar="N",
              help="SUMO vehicles around the ego in every run (red-light violations are counted then).")
@click.option("--udm", metavar="URL", help="Every run queries the UDM at URL (all at once: a fleet against one "
                                           "UDM); its latency p50/p95/p99 goes into the table.")
@click.option("--udm-realtime", is_flag=True,
              help="With --udm: each run's UDM client process under SCHED_FIFO (twin drive --udm-realtime), so "
                   "the fleet's requests preempt the runs' simulations, which stay batch work. Needs root, "
                   "CAP_SYS_NICE or `ulimit -r 10`; otherwise a warning and normal priority.")
@click.option("--pace", type=click.FloatRange(min=0.01), default=None,
              help="Times real time each run may go at most. Default: 1 (real time) with --udm, else unpaced.")
@click.option("--workers", type=click.IntRange(min=1), default=None, metavar="N",
              help="N runs at once on a local Dask cluster (1: one after another, no Dask). Each run is a `twin "
                   "drive` process of its own; the cluster holds them in N threads of at most one process per core.")
@click.option("--scheduler", default=None, metavar="tcp://HOST:PORT",
              help="Runs on the workers of a running Dask scheduler (the build is sent to them; docs/distributed.md).")
@click.option("--timeout", "deadline", type=click.FloatRange(min=1), default=None, metavar="S",
              help="Seconds a run may take before it is killed and counted as timed out (default: 300 + 3 x the "
                   "duration at the pace, or at 4x real time unpaced).")
@click.option("-o", "--output", type=click.Path(file_okay=False, path_type=Path), required=True, metavar="DIR",
              help="Sweep folder: sweep.csv, sweep.json and runs/seed-N/ (metrics.json, collisions.csv, "
                   "udm_latency.csv); written beside it and swapped in when complete.")
@click.option("-q", "--quiet", is_flag=True, help="No line per finished run (`twin -q sweep` too).")
@click.option("--json", "as_json", is_flag=True, help="Print the summary (sweep.json's) as JSON for machines.")
def sweep(map_dir: Path, seeds: str, duration: float, traffic: int, udm: str | None, udm_realtime: bool,
          pace: float | None,
          workers: int | None, scheduler: str | None, deadline: float | None, output: Path, quiet: bool,
          as_json: bool) -> None:
    """Drive one build with many seeds and tabulate the runs.

    \b
    $ twin sweep --map build/sample --seeds 0-15 --duration 60 -o sweeps/sample
    $ twin sweep --map build/tavf --seeds 0-199 --traffic 20 --workers 2 -o sweeps/tavf
    $ twin sweep --map build/tavf --seeds 0-199 --scheduler tcp://10.0.0.5:8786 -o sweeps/tavf
    $ twin sweep --map build/tavf --seeds 0-19 --udm http://127.0.0.1:8765 --duration 120 -o sweeps/udm
    $ twin -q sweep --map build/sample --seeds 0-3 -o sweeps/s --json | jq .worst

    Every run is `twin drive --map BUILD --random --seed N` in its own process, so the same seed gives the
    same drive on any worker. sweep.csv has one row per seed (status, resets, collisions, off-road seconds,
    red-light violations, UDM latency p50/p95/p99, real-time factor); sweep.json adds a summary naming the
    worst runs. Exit codes: 0 every run finished, 1 a run failed or timed out, 2 bad options.
    """
    from tavf_mapkit.fileutil import staged_folder
    from twin.sim.build import Build
    from twin.sweep.plan import DriveOptions, parse_seeds
    from twin.sweep.runs import drive_once
    from twin.sweep.table import COLUMNS, csv_text, run_row, summary

    quiet = quiet or verbosity() < 0
    check_cluster_options(workers, scheduler)
    seed_list = parse_seeds(seeds)
    build = Build.open(map_dir)  # a one-line error for a folder that is not a build, before anything starts
    if udm_realtime and not udm:
        raise click.UsageError("--udm-realtime needs --udm URL")
    options = DriveOptions(duration=duration, traffic=traffic, udm=udm, udm_realtime=udm_realtime,
                           pace=1.0 if udm and pace is None else pace)
    deadline = deadline or options.deadline()
    started = time.perf_counter()
    rows = []

    def finished(row: dict, result: dict) -> None:
        rows.append((row, result["files"]))
        if not quiet:
            what = (f"{row['collisions']} collisions, {row['resets']} resets" if row["status"] == "ok"
                    else f"{row['status']}: {row['error']}")
            click.echo(f"[{len(rows)}/{len(seed_list)}] seed {row['seed']}: {what}", err=True)

    with ExitStack() as stack:
        if wants_cluster(workers, scheduler):
            from tavf_mapkit.cluster import FileFanout, connect, local_processes
            from twin.sweep.runs import drive_task, pack_build

            # a run's task only waits on its `twin drive`: threads of a few quiet processes hold them all
            fanout = stack.enter_context(connect(workers=workers, scheduler=scheduler, waiting_tasks=True))
            packed = pack_build(build.path)
            digest, future = fanout.share(packed)
            runs = FileFanout(fanout, digest, future, build.path.name, reread=lambda: packed).map(
                drive_task, ((seed, options, deadline) for seed in seed_list),
                window=len(seed_list))  # runs are long: all queued, the scheduler balances them
            where = scheduler or f"{workers} local workers ({workers} threads in {local_processes(workers)} processes)"
        else:
            runs = (drive_once(build.path.resolve(), seed, options, deadline) for seed in seed_list)
            where = "this machine, one run at a time"
        for result in runs:
            finished(run_row(result), result)
    seconds = time.perf_counter() - started

    table = [row for row, _ in rows]
    facts = summary(table, str(build.path), {"seeds": seeds, "duration": duration, "traffic": traffic,
                                             "udm": udm, "udm_realtime": udm_realtime, "pace": options.pace, "timeout": deadline},
                    seconds, where)
    with staged_folder(output, marker="sweep.json", what="the sweep folder") as staging:
        (staging / "sweep.csv").write_text(csv_text(table), encoding="utf-8")
        (staging / "sweep.json").write_text(json.dumps({"summary": facts, "columns": list(COLUMNS),
                                                        "runs": table}, indent=1) + "\n", encoding="utf-8")
        for row, files in rows:
            folder = staging / "runs" / f"seed-{row['seed']}"
            folder.mkdir(parents=True)
            for name, data in files.items():
                (folder / name).write_bytes(data)

    if as_json:
        click.echo(json.dumps({**facts, "output": str(output)}, indent=2))
    else:
        _print_summary(facts, seconds, where, output)
    if facts["ok"] < facts["runs"]:
        raise StageError(f"{facts['runs'] - facts['ok']} of {facts['runs']} runs did not finish "
                         f"(see {output / 'sweep.csv'})")


def _print_summary(facts: dict, seconds: float, where: str, output: Path) -> None:
    click.echo(f"{facts['runs']} runs in {seconds:.1f} s on {where}: {facts['ok']} ok, {facts['failed']} failed, "
               f"{facts['timed_out']} timed out; {facts['collisions']} collisions, {facts['resets']} resets, "
               f"{facts['off_road_s']:.2f} s off-road -> {output}")
    for worst in facts["worst"]:
        click.echo(f"  worst: {worst['why']}")
