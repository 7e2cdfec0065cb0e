"""``twin udm``: run a local Urban Dynamic Map and measure how fast it answers a fleet."""

from __future__ import annotations

import json
import logging
import secrets
import sqlite3
from pathlib import Path

import click

from tavf_mapkit.cli.options import Group, json_option, log_level, verbosity
from tavf_mapkit.errors import InputError


@click.group(cls=Group, context_settings={"help_option_names": ["-h", "--help"]})
def udm() -> None:
    """A local Urban Dynamic Map (UDM): an HTTP service of map objects near the car.

    \b
    $ twin udm serve --map build/sample --token s3cret
    $ curl 'http://127.0.0.1:8765/objects?lat=53.55&lon=9.99&radius=150'
    $ twin udm bench-load --url http://127.0.0.1:8765 --vehicles 50 --rate 10 --duration 60
    $ twin udm bench --map build/tavf-dlr --url http://127.0.0.1:8765 --requests 200

    The API, layers and error codes are described in docs/udm-api.md and served at /openapi.json.
    """


@udm.command(renamed={"--seed": "--map"})
@click.option("--db", "db_path", type=click.Path(dir_okay=False, path_type=Path),
              help="SQLite file to keep objects in (created if missing). Default: in memory, gone on exit.")
@click.option("--host", default="127.0.0.1", show_default=True,
              help="Address to listen on. Keep the loopback default unless other machines must reach it.")
@click.option("--port", default=8765, show_default=True, type=click.IntRange(0, 65535),
              help="TCP port; 0 picks a free one (the URL line printed at start says which).")
@click.option("--token", envvar="TWIN_UDM_TOKEN", show_envvar=True,
              help="Bearer token data providers need for POST/DELETE. Default: a random one, printed at "
                   "start.")
@click.option("--map", "seed_dir", type=click.Path(file_okay=False, path_type=Path), metavar="BUILD",
              help="Seed the map from this build folder: its traffic signs and signals (OpenDRIVE signals and objects, OSM nodes, "
                   "signals.geojson) become layer-2 objects before serving.")
@click.option("--purge-interval", default=60.0, show_default=True, type=click.FloatRange(min=0.1),
              help="Seconds between deletions of expired objects (queries never return them anyway).")
@click.option("--realtime", is_flag=True,
              help="Serve under SCHED_FIFO, so on a machine whose cores are busy (a fleet of twins, other jobs) "
                   "a request is answered at once instead of waiting for a core; the server only waits on its "
                   "socket and uses ~1 ms per request. Needs root, CAP_SYS_NICE or `ulimit -r 10`; otherwise a "
                   "warning and normal priority. Pair it with `twin sweep/drive --udm-realtime`.")
@click.option("--json", "as_json", is_flag=True,
              help="Print the start line (url, store, objects, seeded, a generated token) as one JSON line.")
def serve(db_path: Path | None, host: str, port: int, token: str | None, seed_dir: Path | None,
          purge_interval: float, realtime: bool, as_json: bool) -> None:
    """Serve the UDM over HTTP until Ctrl-C.

    \b
    $ twin udm serve --map build/sample
    UDM http://127.0.0.1:8765  store=memory  objects=426  (seeded: osm 412, signals.geojson 0, opendrive 14)
    token: 8fa2...  (set --token or TWIN_UDM_TOKEN to choose one)

    Reads are open to anyone who can reach the port; writes need 'Authorization: Bearer TOKEN':

    \b
    $ curl -X POST -H "Authorization: Bearer $TOKEN" -H 'Content-Type: application/geo+json' \\
        -d @roadworks.geojson http://127.0.0.1:8765/objects

    The log level of the server is the group's: `twin -v udm serve` logs info, -vv debug, -q errors only.
    """
    # Imported here so that `twin --help` does not pay for uvicorn, starlette and osmium.
    from twin.udm.loadgen import is_loopback_host
    from twin.udm.seed import seed_from_build
    from twin.udm.server import create_app, run_server
    from twin.udm.store import IN_MEMORY, SqliteRtreeStore

    if not is_loopback_host(host):
        click.echo(f"note: listening on {host}: anyone who can reach this port can read the map "
                   "(writes still need the token)", err=True)
    generated = not token
    token = token or secrets.token_urlsafe(24)
    if db_path is not None and not db_path.parent.is_dir():
        raise InputError("the folder for the --db file does not exist", file=str(db_path))
    try:
        store = SqliteRtreeStore(db_path if db_path is not None else IN_MEMORY)
    except sqlite3.Error as error:  # not a database, locked, unreadable
        raise InputError(f"cannot open the UDM database: {error}", file=str(db_path)) from None
    seeded = seed_from_build(store, seed_dir) if seed_dir is not None else None

    def announce(url: str) -> None:
        if as_json:
            facts = {"url": url, "store": str(db_path or "memory"), "objects": store.count(), "seeded": seeded,
                     "token": token if generated else None}
            click.echo(json.dumps(facts))
            click.get_text_stream("stdout").flush()
            return
        summary = f"UDM {url}  store={db_path or 'memory'}  objects={store.count()}"
        if seeded is not None:
            summary += "  (seeded: " + ", ".join(f"{name} {count}" for name, count in seeded.items()) + ")"
        # The URL line comes first and is flushed: scripts (and the benchmark) read the port from it.
        click.echo(summary)
        if generated:
            click.echo(f"token: {token}  (set --token or TWIN_UDM_TOKEN to choose one)")
        click.get_text_stream("stdout").flush()

    try:
        run_server(create_app(store, token, purge_interval_s=purge_interval), host, port,
                   on_listening=announce, realtime=realtime,
                   log_level=logging.getLevelName(log_level(verbosity())).lower())
    except OSError as error:
        raise InputError(f"cannot listen on {host}:{port}: {error.strerror or error}") from None
    finally:
        store.close()


@udm.command("bench-load")
@click.option("--url", default="http://127.0.0.1:8765", show_default=True, help="Base URL of the UDM.")
@click.option("--vehicles", default=50, show_default=True, type=click.IntRange(1, 1000),
              help="Simulated vehicles, each with at most one request in flight.")
@click.option("--rate", default=10.0, show_default=True, type=click.FloatRange(0.1, 100.0),
              help="Queries per second per vehicle.")
@click.option("--duration", default=60.0, show_default=True, type=click.FloatRange(0.1, 3600.0),
              help="Seconds to run.")
@click.option("--lat", default=53.55, show_default=True, type=click.FloatRange(-85.0, 85.0),
              help="Centre of the area the fleet drives in.")
@click.option("--lon", default=9.99, show_default=True, type=click.FloatRange(-180.0, 180.0))
@click.option("--area-radius", default=3000.0, show_default=True, type=click.FloatRange(0.0, 50_000.0),
              help="Metres from the centre the vehicles stay within.")
@click.option("--side", default=200.0, show_default=True, type=click.FloatRange(1.0, 10_000.0),
              help="Side in metres of the square each vehicle asks for.")
@click.option("--timeout", default=1.0, show_default=True, type=click.FloatRange(0.01, 60.0),
              help="Seconds before a request counts as a timeout.")
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed for the vehicles' routes.")
@click.option("--allow-remote", is_flag=True,
              help="Permit a URL that is not loopback. Only load a server you run yourself.")
@json_option
def bench_load(url: str, vehicles: int, rate: float, duration: float, lat: float, lon: float,
               area_radius: float, side: float, timeout: float, seed: int, allow_remote: bool,
               as_json: bool) -> None:
    """Load a UDM with a simulated fleet and print latency percentiles.

    \b
    $ twin udm bench-load --url http://127.0.0.1:8765 --vehicles 50 --rate 10 --duration 60
    29950 requests (499.2 Hz), 29950 ok, 0 errors, 0 skipped ticks; 12.3 objects per answer
    latency  p50 2.1 ms, p95 6.4 ms, max 31.0 ms, mean 2.6 ms
    $ twin udm bench-load --duration 10 --json | jq .latency_ms.p95

    Requests are bounded by vehicles x rate x duration; a vehicle whose previous answer is late skips
    ticks (counted as skipped_ticks) rather than queueing more requests. For repeatable numbers with a
    server started for you, see benchmarks/bench_udm_load.py.
    """
    from twin.udm.loadgen import LoadPlan, is_loopback_url, run_load

    if not is_loopback_url(url):
        if not url.startswith(("http://", "https://")):
            raise InputError(f"--url {url!r} is not an http(s) URL")
        if not allow_remote:
            raise InputError(f"--url {url!r} is not a loopback address; pass --allow-remote if you run "
                             "that server")
    plan = LoadPlan(url=url, vehicles=vehicles, rate_hz=rate, duration_s=duration, lat=lat, lon=lon,
                    area_radius_m=area_radius, side_m=side, timeout_s=timeout, seed=seed)
    result = run_load(plan)
    if as_json:
        click.echo(json.dumps(result, indent=2))
        return
    errors = ", ".join(f"{kind} {count}" for kind, count in result["errors_by_kind"].items() if count)
    click.echo(f"{result['requests']} requests ({result['achieved_rate_hz']} Hz), {result['ok']} ok, "
               f"{result['errors']} errors{f' ({errors})' if errors else ''}, {result['skipped_ticks']} skipped "
               f"ticks; {result['objects_per_response']} objects per answer")
    click.echo(f"latency  {_milliseconds(result['latency_ms'], 'p50', 'p95', 'max', 'mean')}")


@udm.command("bench")
@click.option("--map", "map_dir", required=True, type=click.Path(file_okay=False, path_type=Path),
              metavar="BUILD", help="Build folder the twin drives on (with its collision world).")
@click.option("--url", default="http://127.0.0.1:8765", show_default=True, help="Base URL of the UDM.")
@click.option("--requests", default=200, show_default=True, type=click.IntRange(3, 100_000),
              help="Queries on each side (the drive lasts requests x every x 0.05 s of simulated time).")
@click.option("--every", default=10, show_default=True, type=click.IntRange(1, 1000),
              help="The twin asks every N steps (twin drive --udm-every).")
@click.option("--side", default=200.0, show_default=True, type=click.FloatRange(1.0, 10_000.0),
              help="Side in metres of the square asked for (twin drive --udm-bbox).")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the drive's random route.")
@click.option("--timeout", default=1.0, show_default=True, type=click.FloatRange(0.01, 60.0),
              help="Seconds before a request counts as a timeout.")
@click.option("--client", type=click.Choice(["process", "thread"]), default="process", show_default=True,
              help="How the twin runs its UDM client: a child process (the default) or a thread beside the "
                   "simulation (to see what the GIL costs).")
@click.option("--pace", type=click.FloatRange(min=0.01), default=None,
              help="Run the twin at most this many times real time (1 = real time, how a UDM is tested with a "
                   "car in the loop). Default: as fast as it can.")
@click.option("--allow-remote", is_flag=True,
              help="Permit a URL that is not loopback. Only benchmark a server you may load.")
@json_option
def bench(map_dir: Path, url: str, requests: int, every: int, side: float, seed: int, timeout: float,
          client: str, pace: float | None, allow_remote: bool, as_json: bool) -> None:
    """Compare UDM latency from inside a running twin with the same requests sent standalone.

    \b
    $ twin udm bench --map build/tavf-dlr --url http://127.0.0.1:8765 --requests 200
    standalone  mean 3.4 ms, p95 5.0 ms
    in twin     mean 3.5 ms, p95 5.1 ms
    overhead    1.02x mean, 1.02x p95 (target <= 1.05x): met
    $ twin udm bench --map build/tavf-dlr --json | jq .overhead_ratio

    It needs a UDM running, e.g. `twin udm serve --map build/tavf-dlr &`.

    The twin drives a random route with the UDM hook; its queries (centres, side, intervals) are then sent
    again from this process by a plain client. Both are timed with time.monotonic() from publish to the
    parsed answer; overhead_ratio = mean in twin / mean standalone. See benchmarks/bench_udm_overhead.py.
    """
    from twin.udm.bench import run_bench
    from twin.udm.loadgen import is_loopback_url

    if not url.startswith(("http://", "https://")):
        raise InputError(f"--url {url!r} is not an http(s) URL")
    if not is_loopback_url(url) and not allow_remote:
        raise InputError(f"--url {url!r} is not a loopback address; pass --allow-remote if you may load it")
    result = run_bench(map_dir, url, requests, every=every, side_m=side, seed=seed, timeout_s=timeout,
                       client=client, pace=pace)
    if as_json:
        click.echo(json.dumps(result, indent=2))
        return
    twin, errors = result["twin"], result["errors"]
    click.echo(f"standalone  {_milliseconds(result['standalone_ms'], 'mean', 'p95')}")
    click.echo(f"in twin     {_milliseconds(result['in_twin_ms'], 'mean', 'p95')}")
    verdict = "met" if result["meets_target"] else "NOT met"
    click.echo(f"overhead    {result['overhead_ratio']}x mean, {result['overhead_ratio_p95']}x p95 "
               f"(target <= {result['target_ratio']}x): {verdict}")
    click.echo(f"twin        {twin['real_time_factor']}x real time, {twin['queries']} queries, {twin['answers']} "
               f"answers; errors {errors['in_twin']} in twin, {errors['standalone']} standalone")


def _milliseconds(stats: dict | None, *keys: str) -> str:
    """``p50 2.1 ms, p95 6.4 ms`` of a latency summary (none when nothing was answered)."""
    if not stats or all(stats.get(key) is None for key in keys):
        return "no answers"
    return ", ".join(f"{key} {stats[key]} ms" for key in keys)
