"""The ego among SUMO traffic in a real ``twin drive`` session, and its behaviour rules on their own."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from twin.session.config import DriveConfig
from twin.session.loop import Session
from twin.traffic.behaviour import EgoBehaviour, safe_speed
from twin.traffic.hook import TrafficHook
from twin.traffic.sumo import Actors, SignalLinks, TrafficSnapshot


class WatchedTrafficHook(TrafficHook):
    """The real hook, plus a log of why the ego's speed was capped each step."""

    def __init__(self, options):
        super().__init__(options)
        self.log = []

    def target_speed(self, session, t, speed):
        value = super().target_speed(session, t, speed)
        self.log.append((t, session.ego.speed, self.behaviour.last.reason,
                         None if self.behaviour._approach is None
                         else self.snapshot.signal_state[self.behaviour._approach[0]]))
        return value


def drive(build, out, seed, duration, traffic, record=False):
    config = DriveConfig(map=build, out=out, random=True, duration=duration, seed=seed, plot=False,
                         plugins={"traffic": traffic, "record": record})
    hook = WatchedTrafficHook(config.as_dict())
    metrics = Session(config, [hook]).run()
    return metrics, hook


@pytest.mark.slow
def test_ego_stops_at_red_and_keeps_off_traffic(sample_build_dir, tmp_path):
    _, hook = drive(sample_build_dir, tmp_path / "a", seed=0, duration=40, traffic=10)
    on_disk = json.loads((tmp_path / "a" / "metrics.json").read_text())
    assert on_disk["red_light_violations"] == 0 and on_disk["collisions"] == 0
    assert on_disk["traffic"]["collisions"] == 0 and on_disk["hook_errors"] == 0
    stopped_at_red = [t for t, v, reason, state in hook.log if reason == "signal" and state == "r" and v < 0.1]
    assert stopped_at_red, "the drive never waited at a red light"
    # same seed: the same ego trajectory, although SUMO traffic reacted to it
    drive(sample_build_dir, tmp_path / "b", seed=0, duration=40, traffic=10)
    assert (tmp_path / "a" / "trajectory.csv").read_bytes() == (tmp_path / "b" / "trajectory.csv").read_bytes()


@pytest.mark.slow
def test_a_car_that_teleports_leaves_the_traffic_running(perth_build, tmp_path):
    """Perth, 30 cars, seed 0: at step 2855 a car jammed behind the ego starts to teleport and is removed. The
    step's subscription results still held it, off the network (SUMO's invalid-value sentinel, a 2D position),
    and its subscription outlived it: the snapshot failed, and the traffic hook was disabled for the rest of
    the drive."""
    drive(perth_build, tmp_path / "a", seed=0, duration=150, traffic=30)
    on_disk = json.loads((tmp_path / "a" / "metrics.json").read_text())
    assert on_disk["traffic"]["teleports_removed"] >= 1
    assert on_disk["hook_errors"] == 0, on_disk.get("hook_error_messages")


def _snapshot(xs, speeds, yaws=None, persons=None, signal_state=()):
    n = len(xs)
    persons = np.zeros(n, dtype=bool) if persons is None else np.asarray(persons)
    actors = Actors(tuple(f"a{i}" for i in range(n)), persons, ("car",) * n, ("e",) * n,
                    np.asarray(xs, dtype=float), np.zeros(n), np.zeros(n),
                    np.zeros(n) if yaws is None else np.asarray(yaws, dtype=float), np.asarray(speeds, dtype=float),
                    np.where(persons, 0.3, 5.0), np.where(persons, 0.5, 1.8), np.full(n, 1.5), np.zeros(n, bool),
                    np.asarray(xs, dtype=float), np.zeros(n))
    return TrafficSnapshot(0, 0.0, actors, np.array(list(signal_state), dtype="<U1"))


def _links(stop_x):
    return SignalLinks(("tls",), np.array([0]), ("in",), ("out",), np.array([stop_x]), np.array([0.0]),
                       np.array([0.0]), np.array([stop_x + 15.0]), np.array([0.0]))


NO_SIGNALS = SignalLinks((), np.array([], dtype=int), (), (), *(np.array([]),) * 5)


def simulate(behaviour, snapshot_at, steps=1200, dt=0.05, v0=13.9, response_s=0.5, max_decel=8.0):
    """A point car on the x axis whose speed follows the cap with a first-order lag (a controller's)."""
    x, v = 0.0, v0
    path = np.column_stack([np.linspace(0, 300, 301), np.zeros(301), np.zeros(301)])
    trace = []
    for k in range(steps):
        t = k * dt
        snapshot = snapshot_at(t)
        cap = behaviour.cap(t, (x, 0.0), 0.0, v, path[path[:, 0] >= x - 1.0], snapshot)
        target = min(v0, cap.speed)
        v = max(0.0, v + max(-max_decel * dt, min(2.0 * dt, (target - v) * dt / response_s)))
        x += v * dt
        trace.append((t, x, v, cap.reason))
    return trace


def test_follows_a_slower_leader_without_touching_it():
    behaviour = EgoBehaviour(NO_SIGNALS, 4.97, 1.96)
    leader_start, leader_speed = 40.0, 4.0
    trace = simulate(behaviour, lambda t: _snapshot([leader_start + leader_speed * t + 2.5], [leader_speed]))
    gaps = [leader_start + leader_speed * t - (x + 2.485) for t, x, _, _ in trace]
    assert min(gaps) > 1.0  # bumper to bumper
    assert abs(trace[-1][2] - leader_speed) < 0.2  # settled behind it at its speed
    assert any(reason == "leader" for *_, reason in trace)


def test_stops_for_red_goes_on_green_and_counts_a_violation():
    links = _links(60.0)
    behaviour = EgoBehaviour(links, 4.97, 1.96)
    trace = simulate(behaviour, lambda t: _snapshot([], [], signal_state="r" if t < 30.0 else "G"))
    stop_x = max(x for t, x, _, _ in trace if t < 30.0)
    assert 60.0 - 3.0 < stop_x + 2.485 < 60.0  # the front bumper stops before the line
    assert trace[-1][1] > 100.0 and behaviour.red_light_violations == 0
    # a car that cannot brake runs the red light: counted once
    reckless = EgoBehaviour(links, 4.97, 1.96)
    simulate(reckless, lambda t: _snapshot([], [], signal_state="r"), steps=200, max_decel=0.0)
    assert reckless.red_light_violations == 1


def test_yields_to_a_person_on_the_path_but_not_beside_it():
    behaviour = EgoBehaviour(NO_SIGNALS, 4.97, 1.96)
    on_path = _snapshot([50.0], [0.0], persons=[True])
    trace = simulate(behaviour, lambda t: on_path if t < 20.0 else _snapshot([], []))
    stop = max(x for t, x, _, _ in trace if t < 20.0)
    assert 50.0 - 0.25 - 2.485 - stop >= 1.5 and trace[-1][1] > 100.0
    beside = _snapshot([50.0], [0.0], persons=[True])
    beside = TrafficSnapshot(0, 0.0, Actors(*[getattr(beside.actors, f) for f in (
        "ids", "is_person", "type_id", "road_id", "x")], np.array([4.0]), *[getattr(beside.actors, f) for f in (
            "z", "yaw", "speed", "length", "width", "height", "placed", "sumo_x", "sumo_y")]), beside.signal_state)
    assert behaviour.cap(0.0, (0.0, 0.0), 0.0, 10.0, np.array([[0, 0, 0], [100, 0, 0]]), beside).reason == ""


def test_safe_speed_is_krauss():
    # v*tau + v^2/(2b) = gap + vl^2/(2b) at the returned v
    v = float(safe_speed(30.0, 5.0, 4.0, 1.5))
    assert v * 1.5 + v * v / 8.0 == pytest.approx(30.0 + 25.0 / 8.0)
    assert float(safe_speed(-3.0, 0.0, 4.0, 1.0)) == 0.0
    assert math.isfinite(float(safe_speed(1e6, 0.0, 4.0, 1.0)))
