"""``twin drive``: drive the simulated Tesla Model S through a build, headless, and write what happened."""

from __future__ import annotations

import json
from pathlib import Path

import click

from tavf_mapkit.cli.options import FORMAT_TO_JSON, Command, json_option
from tavf_mapkit.errors import InputError


def _bias(value: str | None) -> tuple[float, float, float]:
    if not value:
        return (0.0, 0.0, 0.0)
    try:
        parts = tuple(float(v) for v in value.split(","))
    except ValueError:
        raise InputError(f"--gnss-bias must be E,N,U in metres, not {value!r}") from None
    if len(parts) != 3:
        raise InputError(f"--gnss-bias must be E,N,U in metres, not {value!r}")
    return parts


@click.command(cls=Command, renamed={"--out": "--output", "--format": FORMAT_TO_JSON},
               context_settings={"help_option_names": ["-h", "--help"]})
@click.option("--map", "map_dir", required=True, type=click.Path(path_type=Path), metavar="BUILD",
              help="A build folder made by `mapkit build` (with its collision world).")
@click.option("--route", type=click.Path(path_type=Path), metavar="TRACE",
              help="Drive a recorded GNSS trace (GPX, GeoJSON, CSV, ride JSON, ROS 1/2 bag): it is map-matched "
                   "to a lane route, driven at the recorded speed.")
@click.option("--route-mode", type=click.Choice(["replay", "legal"]), default="replay", show_default=True,
              help="replay: drive the matched lane centres in recording order, wherever the recording went; "
                   "legal: the cheapest connected lane route through the matched lanes, as a car may drive.")
@click.option("--random", "random_route", is_flag=True,
              help="Drive random routes that always make progress: around the map's closed loops, else turning "
                   "around at dead ends, else restarting (docs/twin.md, Routes).")
@click.option("--duration", type=click.FloatRange(min=0, min_open=True), metavar="S",
              help="Simulated seconds. Default: 60 for --random, the whole trace for --route.")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of every random choice and noise.")
@click.option("--speed", "speed_kmh", type=click.FloatRange(min=0, min_open=True), metavar="KMH",
              help="Fixed target speed in km/h instead of the lane's limit / the recorded speed "
                   "(bends still slow the car down).")
@click.option("--controller", type=click.Choice(["pure-pursuit", "pid"]), default="pure-pursuit",
              show_default=True, help="Lateral controller; pid is CARLA's LocalPlanner PID (K_P 1.95, K_I 0.05, "
                                      "K_D 0.2).")
@click.option("--dt", type=click.FloatRange(min=0.001, max=0.5), default=0.05, show_default=True,
              help="Fixed step in seconds.")
@click.option("--pace", type=click.FloatRange(min=0.01), default=None,
              help="Run at most this many times real time (1 = real time, e.g. with a real UDM or hardware in "
                   "the loop). Default: as fast as the machine allows. Results do not depend on it.")
@click.option("--vehicles", type=click.IntRange(min=1), default=1, show_default=True,
              help="Twin-driven cars on random routes, the ego included (not SUMO traffic: see --traffic).")
@click.option("--gnss-rate", type=click.FloatRange(min=0, min_open=True), default=10.0, show_default=True,
              metavar="HZ", help="GNSS fixes per second.")
@click.option("--gnss-noise", type=click.FloatRange(min=0), default=0.0, show_default=True, metavar="M",
              help="GNSS noise: standard deviation per axis (east, north, up) in metres.")
@click.option("--gnss-bias", metavar="E,N,U", help="Constant GNSS error per axis in metres.")
@click.option("--lidar/--no-lidar", default=False, show_default=True,
              help="32 x 1024 lidar at 10 Hz (pybullet ray casts).")
@click.option("--camera/--no-camera", default=False, show_default=True,
              help="320 x 240 forward camera at 5 Hz (TinyRenderer); the last frame goes to camera.png.")
@click.option("--gui", is_flag=True, help="Show the pybullet GUI (falls back to headless without a display).")
@click.option("-o", "--output", "out_dir", type=click.Path(path_type=Path), default=Path("drive-out"),
              show_default=True, metavar="DIR", help="Output folder (written to a temporary folder, then renamed into place).")
@click.option("--no-plot", is_flag=True, help="Skip drive.png.")
@click.option("--udm", metavar="URL", help="Query an Urban Dynamic Map at URL around each GNSS fix.")
@click.option("--udm-every", type=click.IntRange(min=1), default=10, show_default=True, metavar="N",
              help="Query the UDM every N steps.")
@click.option("--udm-bbox", type=click.FloatRange(min=0, min_open=True), default=200.0, show_default=True,
              metavar="M", help="Side of the square queried around the fix, metres.")
@click.option("--udm-realtime", is_flag=True,
              help="Run the drive's UDM client process under SCHED_FIFO, so on a busy machine its requests "
                   "preempt other work instead of waiting for a core; the simulation keeps its priority (so a "
                   "thread client, which shares its process, is never raised). Needs root, CAP_SYS_NICE or "
                   "`ulimit -r 10`; otherwise a warning and normal priority.")
@click.option("--record/--no-record", default=None,
              help="Record the session as MCAP (default: on when the recorder is installed).")
@click.option("--traffic", type=click.IntRange(min=0), default=0, show_default=True, metavar="N",
              help="SUMO vehicles around the ego (libsumo co-simulation).")
@click.option("--pedestrians", type=click.IntRange(min=0), default=0, show_default=True, metavar="M",
              help="SUMO pedestrians.")
@click.option("--demand", type=click.Path(dir_okay=False, path_type=Path), metavar="ROUTES.rou.xml",
              help="SUMO demand file instead of generated traffic.")
@click.option("--view", is_flag=True,
              help="Show the drive live in the browser (the 3D view and 2D map of `mapkit view`), on 127.0.0.1 "
                   "while it runs; it never slows the loop down by waiting (docs/view.md, Live).")
@click.option("--view-port", type=click.IntRange(0, 65535), default=8790, show_default=True, metavar="N",
              help="Port of --view on 127.0.0.1 (0: any free port).")
@click.option("--view-rate", type=click.FloatRange(min=0, min_open=True, max=60), default=10.0, show_default=True,
              metavar="HZ", help="Updates of --view per wall-clock second.")
@click.option("--no-browser", is_flag=True, help="With --view: print the address, do not open a browser.")
@json_option
def drive(map_dir, route, route_mode, random_route, duration, seed, speed_kmh, controller, dt, pace, vehicles, gnss_rate, gnss_noise,
          gnss_bias, lidar, camera, gui, out_dir, no_plot, udm, udm_every, udm_bbox, udm_realtime, record, traffic, pedestrians,
          demand, view, view_port, view_rate, no_browser, as_json) -> None:
    """Drive a simulated Tesla Model S through a build and write what happened.

    \b
    $ twin drive --map build/sample --random --duration 60
    $ twin drive --map build/tavf-dlr --route ride.json -o runs/ride
    $ twin drive --map build/tavf-dlr --random --duration 1800 --seed 7 --gnss-noise 0.5
    $ twin -v drive --map build/sample --random -o runs/a --json | jq .collisions
    $ twin drive --map build/sample --random --duration 600 --traffic 40 --view   # watch it in the browser

    Writes DIR/trajectory.csv (t,x,y,z,yaw,speed,lat,lon,road,lane), DIR/gnss.csv, DIR/imu.csv,
    DIR/collisions.csv, DIR/metrics.json and DIR/drive.png. Same seed and inputs give byte-identical
    trajectory.csv. Metrics are explained in docs/twin.md.
    """
    from twin.session.config import DriveConfig
    from twin.session.loop import Session
    from twin.session.plugins import create_hooks

    if route is not None and random_route:
        raise click.UsageError("choose one of --route and --random")
    if route is None and not random_route:
        raise click.UsageError("choose a route: --random or --route TRACE")
    plugins = {"udm": udm, "udm_every": udm_every, "udm_bbox": udm_bbox, "udm_realtime": udm_realtime, "record": record, "traffic": traffic,
               "pedestrians": pedestrians, "demand": str(demand) if demand else None}
    config = DriveConfig(map=map_dir, out=out_dir, route=route, route_mode=route_mode, random=random_route, duration=duration, seed=seed,
                         speed_kmh=speed_kmh, dt=dt, controller=controller, vehicles=vehicles, gnss_rate=gnss_rate,
                         gnss_noise=gnss_noise, gnss_bias=_bias(gnss_bias), lidar=lidar, camera=camera, gui=gui,
                         plot=not no_plot, pace=pace, plugins=plugins)
    hooks = create_hooks(config.as_dict())
    if view:  # not a drive option (a re-simulation opens no view): the last hook, seeing the others' step
        from twin.view.hook import LiveViewHook

        hooks.append(LiveViewHook(map_dir, port=view_port, rate_hz=view_rate, browser=not no_browser))
    metrics = Session(config, hooks).run()
    if as_json:
        click.echo(json.dumps(metrics, indent=2))
        return
    click.echo(f"drove {metrics['sim_seconds']:.1f} s ({metrics['distance_m']:.0f} m) in {metrics['wall_seconds']:.2f} s"
               f" wall: {metrics['real_time_factor']}x real time -> {out_dir}")
    click.echo(f"resets {metrics['resets']}  collisions {metrics['collisions']}  off-road "
               f"{metrics['off_road_seconds']:.2f} s  lateral error mean {metrics['lateral_error_mean_m']:.3f} m")
    if metrics.get("turnarounds") or metrics.get("restarts"):
        click.echo(f"routes ({metrics.get('route_mode')} mode): {metrics['turnarounds']} turnarounds at dead ends, "
                   f"{metrics['restarts']} restarts (see docs/twin.md, Routes)")
    if "trace_distance_mean_m" in metrics:
        click.echo(f"trace: distance to the driven path {metrics['trace_distance_mean_m']:.3f} m mean, noise floor "
                   f"{metrics['trace_floor_mean_m']:.3f} m ({metrics['trace_fixes_matched']} matched fixes)")
    if metrics.get("hook_errors"):
        click.echo(f"warning: {metrics['hook_errors']} hook error(s), see metrics.json", err=True)
