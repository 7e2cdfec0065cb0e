"""Co-simulated traffic: ego + 100 SUMO vehicles + 20 pedestrians on DLR's TAVF build, UDM publishing at 10 Hz.

    $ .venv/bin/python benchmarks/bench_traffic.py --map build/tavf-dlr            # 60 s, the figure for the record
    $ .venv/bin/python benchmarks/bench_traffic.py --map build/tavf-dlr --duration 20

The build must have its collision world (``mapkit build ../shared/data/hamburg/tavf_dlr_sumo_net/network.net.xml.gz
-o build/tavf-dlr``). The UDM server runs in its own process (``twin udm serve``) on a free loopback port; the
drive records its MCAP file as ``twin drive`` does. Printed: the real-time factor against the target (>= 10x)
and against the same drive without traffic (the peer measured in the same run), and where the step time goes:
SUMO (libsumo step + reading its state), physics (the twin's own vehicle, pybullet, control, sensors), traffic
in pybullet (boxes, contacts, behaviour), UDM (handing snapshots to the publisher process, which builds and
posts the features) and recording.
"""

from __future__ import annotations

import argparse
import json
import secrets
import subprocess
import sys
import tempfile
import time
from pathlib import Path

TARGET_RTF = 10.0


class Timed:
    """Wraps a hook and adds up the wall time of each of its calls."""

    def __init__(self, hook) -> None:
        self.hook = hook
        self.name = hook.name
        self.seconds = 0.0

    def _timed(self, method, *args):
        started = time.perf_counter()
        try:
            return getattr(self.hook, method)(*args)
        finally:
            self.seconds += time.perf_counter() - started

    def start(self, session):  # setup is not part of the loop's wall time
        return self.hook.start(session)

    def before_step(self, session, t):
        return self._timed("before_step", session, t)

    def target_speed(self, session, t, speed):
        return self._timed("target_speed", session, t, speed)

    def after_step(self, session, frame):
        return self._timed("after_step", session, frame)

    def finish(self, session, metrics):
        return self.hook.finish(session, metrics)


def start_udm(token: str) -> tuple[subprocess.Popen, str]:
    twin = Path(sys.executable).parent / "twin"
    process = subprocess.Popen([str(twin), "udm", "serve", "--port", "0", "--token", token],
                               stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    line = process.stdout.readline()
    if not line.startswith("UDM "):
        process.kill()
        raise SystemExit(f"twin udm serve did not start: {line!r}")
    return process, line.split()[1]


def drive(build: Path, out: Path, duration: float, seed: int, traffic: int, pedestrians: int, udm_url: str | None,
          token: str | None):
    from twin.session.config import DriveConfig
    from twin.session.loop import Session
    from twin.session.plugins import create_hooks

    plugins = {"traffic": traffic, "pedestrians": pedestrians, "udm": None, "record": True,
               "udm_token": token}
    config = DriveConfig(map=build, out=out, random=True, duration=duration, seed=seed, plot=False, plugins=plugins)
    options = config.as_dict()
    hooks = [hook for hook in create_hooks(options) if hook.name != "udm"]
    for hook in hooks:
        if hook.name == "traffic":  # publish only: the ego's own UDM queries are bench_udm_load's subject
            hook.udm_url, hook.udm_token = udm_url, token
    timed = [Timed(hook) for hook in hooks]
    metrics = Session(config, timed).run()
    return metrics, {t.name: t for t in timed}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--map", type=Path, default=Path("build/tavf-dlr"))
    parser.add_argument("--duration", type=float, default=60.0)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--vehicles", type=int, default=100)
    parser.add_argument("--pedestrians", type=int, default=20)
    args = parser.parse_args()
    if not (args.map / "collision").is_dir():
        raise SystemExit(f"{args.map} has no collision world; build it with mapkit build (see --help)")
    token = secrets.token_hex(16)
    server, url = start_udm(token)
    try:
        with tempfile.TemporaryDirectory() as scratch:
            base, _ = drive(args.map, Path(scratch) / "base", args.duration, args.seed, 0, 0, None, None)
            metrics, timed = drive(args.map, Path(scratch) / "traffic", args.duration, args.seed, args.vehicles,
                                   args.pedestrians, url, token)
    finally:
        server.terminate()
        server.wait(10)
    wall = metrics["wall_seconds"]
    section = metrics["traffic"]
    seconds = section["seconds"]
    record_hook = timed["record"].seconds if "record" in timed else 0.0
    traffic_hook = timed["traffic"].seconds
    shares = {
        "sumo (libsumo step + reading its state)": seconds["sumo"],
        "physics, control, sensors (the rest)": wall - traffic_hook - record_hook,
        "traffic in pybullet (boxes, contacts, behaviour)": seconds["bodies"] + seconds["contacts"] + seconds["behaviour"],
        "udm (handing snapshots to the publisher process)": seconds["udm"],
        "recording (ego + traffic)": record_hook + seconds["record"],
    }
    rtf = metrics["real_time_factor"]
    print(f"TAVF build {args.map}: ego + {args.vehicles} SUMO vehicles + {args.pedestrians} pedestrians, "
          f"{args.duration:g} s simulated at dt {metrics['dt']}, UDM publishing at 10 Hz to {url}")
    print(f"{'real-time factor':<52} {rtf:8.1f}x   target >= {TARGET_RTF:g}x  "
          f"({'met' if rtf >= TARGET_RTF else 'MISSED'}, {rtf / TARGET_RTF:.2f} of the target)")
    print(f"{'peer: same drive without traffic':<52} {base['real_time_factor']:8.1f}x   "
          f"traffic costs {base['real_time_factor'] / max(rtf, 1e-9):.2f}x")
    steps = metrics["steps"]
    print(f"{'step time':<52} {1000 * wall / steps:8.3f} ms")
    for name, value in shares.items():
        print(f"  {name:<50} {1000 * value / steps:8.3f} ms  {100 * value / wall:5.1f} %")
    udm = section.get("udm", {})
    posts = udm.get("posts", 0)
    print(f"UDM: {udm.get('snapshots_sent', 0)} snapshots handed over, {udm.get('snapshots_held', 0)} replaced while "
          f"held (wall interval {udm.get('min_interval_s', 0):g} s), {posts} POSTs ({posts / max(wall, 1e-9):.1f} per "
          f"wall second, {posts / args.duration:.1f} per simulated second), {udm.get('objects', 0)} objects, "
          f"errors {udm.get('errors', {})}")
    print(f"traffic: inserted {section['inserted_vehicles']} vehicles / {section['inserted_persons']} persons, "
          f"teleports removed {section['teleports_removed']}, collisions {section['collisions']}, "
          f"red-light violations {metrics['red_light_violations']}")
    print(json.dumps({"real_time_factor": rtf, "target": TARGET_RTF, "peer_real_time_factor": base["real_time_factor"],
                      "step_ms": 1000 * wall / steps,
                      "shares": {k: round(v / wall, 4) for k, v in shares.items()}}))


if __name__ == "__main__":
    main()
