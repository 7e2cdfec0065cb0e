"""Controllers (CARLA's PID semantics, pure pursuit geometry) and the path buffer's planning queries."""

from __future__ import annotations

import math

import numpy as np
import pytest

from twin.control.pid import (
    CARLA_LIMITS,
    PidGains,
    PidLateral,
    PidLongitudinal,
    PidTerm,
    heading_error,
    limit_steering,
    split_acceleration,
)
from twin.control.purepursuit import PurePursuit
from twin.planning.buffer import JOIN_BOW, PathBuffer, join_cut, join_gap, straight_cut
from twin.planning.chunks import PathChunk
from twin.vehicle.params import MODEL_S


def test_pid_term_uses_carlas_ten_error_window():
    term = PidTerm(PidGains(1.0, 0.5, 0.1), 1, 0.05)
    errors = [0.01 * k for k in range(1, 15)]
    for e in errors:
        out = term(np.array([e]))
    window = errors[-10:]
    expected = 1.0 * errors[-1] + 0.1 * (errors[-1] - errors[-2]) / 0.05 + 0.5 * sum(window) * 0.05
    assert expected < 1.0 and out[0] == pytest.approx(expected)
    term = PidTerm(PidGains(1.0, 0.5, 0.1), 1, 0.05)
    assert term(np.array([0.2]))[0] == pytest.approx(0.2)  # one error: no derivative, no integral yet


@pytest.mark.parametrize("dt", [0.01, 0.025, 0.05, 0.1])
def test_pid_term_works_in_seconds_whatever_the_step(dt):
    """CARLA's window is 0.5 s (10 errors at 20 Hz) and the derivative is per second: an error growing at
    0.2 per second gives (nearly) the same output at any step."""
    rate, steps = 0.2, round(2.0 / dt)
    term = PidTerm(PidGains(1.0, 0.5, 0.1), 1, dt)
    assert term.window == round(0.5 / dt)
    for k in range(steps):
        out = term(np.array([rate * k * dt]))
    error = rate * (steps - 1) * dt
    window_mean = error - rate * (0.5 - dt) / 2  # mean of the ramp's last 0.5 s of errors
    expected = 1.0 * error + 0.1 * rate + 0.5 * window_mean * 0.5
    assert expected < 1.0 and out[0] == pytest.approx(expected, rel=1e-9)
    assert out[0] == pytest.approx(0.4 + 0.02 + 0.5 * 0.35 * 0.5, abs=0.03)  # the same car at any step
    with pytest.raises(ValueError, match="dt must be a positive number of seconds, not 0"):
        PidTerm(PidGains(1.0, 0.5, 0.1), 1, 0)


def test_carla_defaults_and_actuator_limits():
    lateral, longitudinal = PidLateral(1, 0.05), PidLongitudinal(1, 0.05)
    assert (lateral.term.gains.k_p, lateral.term.gains.k_i, lateral.term.gains.k_d) == (1.95, 0.05, 0.2)
    assert (longitudinal.term.gains.k_p, longitudinal.term.gains.k_i, longitudinal.term.gains.k_d) == (1.0, 0.05, 0)
    throttle, brake = split_acceleration(np.array([0.9, -0.9, 0.2]), CARLA_LIMITS)
    assert throttle.tolist() == [0.75, 0.0, 0.2] and brake.tolist() == [0.0, 0.3, 0.0]
    # the steering slews 2.0 per second: CARLA's 0.1 per step at 20 Hz, 0.05 at 40 Hz
    assert limit_steering(np.array([1.0]), np.array([0.0]), CARLA_LIMITS, 0.05)[0] == 0.1
    assert limit_steering(np.array([1.0]), np.array([0.0]), CARLA_LIMITS, 0.025)[0] == 0.05
    assert limit_steering(np.array([1.0]), np.array([0.75]), CARLA_LIMITS, 0.05)[0] == pytest.approx(0.8)
    # below junction speed the local planner lets the wheel go to full lock (per vehicle), at the same rate
    full = limit_steering(np.array([1.0, 1.0, -1.0]), np.array([0.75, 0.95, -0.95]), CARLA_LIMITS, 0.05,
                          np.array([0.8, 1.0, 1.0]))
    assert full == pytest.approx([0.8, 1.0, -1.0])
    # the longitudinal error is in km/h as in CARLA: 1 m/s short of the target saturates K_P=1
    assert longitudinal(np.array([10.0]), np.array([11.0]))[0] == 1.0


def test_heading_error_sign():
    assert heading_error(0.0, 0.0, 0.0, 1.0, 1.0) == pytest.approx(math.pi / 4)  # target on the left
    assert heading_error(0.0, 0.0, math.pi / 2, 1.0, 1.0) == pytest.approx(-math.pi / 4)


def test_pure_pursuit_steers_onto_the_circle_through_the_target():
    controller = PurePursuit(1)
    radius = 20.0
    rear = np.array([0.0, 0.0])  # rear axle at the origin heading +x: the circle's centre is (0, R)
    angle = 0.4
    target = np.array([radius * math.sin(angle), radius - radius * math.cos(angle)])
    cg = rear + np.array([MODEL_S.cg_to_rear_axle, 0.0])
    steer = controller.steer(cg[0:1], cg[1:2], np.zeros(1), np.zeros(1), target[0:1], target[1:2], MODEL_S)
    assert steer[0] * MODEL_S.max_steer == pytest.approx(math.atan(MODEL_S.wheelbase / radius))


def _buffer_with(points, speed=10.0, count=1, **kwargs):
    buffer = PathBuffer(count, **kwargs)
    chunk = PathChunk(points, np.full(len(points), speed), np.zeros(len(points), dtype=np.int64))
    for i in range(count):
        buffer.assign(i, iter([chunk]))
    return buffer


def test_projection_and_lookahead_on_a_straight_path():
    xs = np.arange(0.0, 100.0, 1.0)
    buffer = _buffer_with(np.column_stack([xs, np.zeros_like(xs), 0.01 * xs]), count=2)
    projection = buffer.project(np.array([10.3, 40.5]), np.array([0.5, -1.0]))
    assert projection.s[0] == pytest.approx(10.3)
    # the search window (24 segments) keeps projections local: vehicle 1, 40 m ahead, is not found at x=40
    assert projection.s[1] == pytest.approx(24.0)
    assert projection.lateral[0] == pytest.approx(0.5) and projection.z[0] == pytest.approx(0.103)
    tx, ty = buffer.point_at(projection.s + 5.0)
    assert tx[0] == pytest.approx(15.3) and ty[0] == pytest.approx(0.0)


def test_curvature_limits_speed_and_the_end_of_a_finite_route_stops_the_car():
    radius = 15.0
    angles = np.arange(0.0, math.pi, 1.0 / radius)
    arc = np.column_stack([radius * np.sin(angles), radius - radius * np.cos(angles), np.zeros_like(angles)])
    straight = np.column_stack([np.arange(-60.0, 0.0, 1.0), np.zeros(60), np.zeros(60)])
    buffer = _buffer_with(np.concatenate([straight, arc]), speed=20.0, lateral_accel=2.5)
    inside = buffer.vmax[0, 70:80]
    assert np.allclose(inside, math.sqrt(2.5 * radius), rtol=0.02)
    buffer.project(np.array([-60.0]), np.array([0.0]))
    # braking at 2 m/s^2 from the straight's start towards the bend: sqrt(v_bend^2 + 2 a d)
    allowed = buffer.allowed_speed(buffer.s[:, 0], 2.0)
    assert allowed[0] == pytest.approx(min(20.0, math.sqrt(2.5 * radius + 2 * 2.0 * 59.0)), rel=0.03)
    assert buffer.vmax[0, buffer.count[0] - 1] == 0.0 and buffer.exhausted[0]


def _joined(*chunks):
    buffer = PathBuffer(1)
    buffer.assign(0, iter([PathChunk(c, np.full(len(c), 10.0), np.full(len(c), k, dtype=np.int64))
                           for k, c in enumerate(chunks)]))
    n = int(buffer.count[0])
    return buffer.x[0, :n], buffer.y[0, :n], buffer.lane[0, :n], buffer.s[0, :n]


def test_a_chunk_that_starts_behind_the_paths_end_joins_on_a_diagonal_forwards():
    """Taipei: a junction's connecting lane starts 4.7 m before the end of the road leading into it. The path
    crosses over to its start on a straight diagonal (``join_cut``); the blend once shortened the path and
    then appended the chunk behind the old end, so the path ran 4.7 m back: the car turned round after it,
    left the path and hit a building."""
    road = np.column_stack([np.arange(0.0, 60.0, 1.0), np.zeros(60), np.zeros(60)])
    junction = np.column_stack([np.arange(55.0, 70.0, 1.0), np.full(15, 1.0), np.zeros(15)])
    x, y, lane, s = _joined(road, junction)
    assert np.all(np.diff(x) > 0)  # forwards all the way
    assert join_gap(np.array([59.0, 0.0]), 0.0, np.array([55.0, 1.0])) == pytest.approx((-4.0, 1.0))
    assert x[lane == 0].max() == pytest.approx(59.0 - join_cut(-4.0, 1.0), abs=1.0)
    assert (x[-1], y[-1]) == (69.0, 1.0) and np.all(np.diff(s) > 0)


def test_a_chunk_that_goes_on_in_line_is_joined_without_a_diagonal():
    """Town07: the sub-metre lanes at the end of a junction's right turn are stepped over, leaving a gap of
    1.9 m straight ahead. Sized by the whole gap, the blend replaced the last 15 m of the turn by a diagonal,
    and the car cut the corner onto the junction's curb; in line, a straight joins the two."""
    angle = np.linspace(0.0, math.pi / 2, 30)
    turn = np.column_stack([10.0 * np.sin(angle), 10.0 * np.cos(angle) - 10.0, np.zeros(30)])  # right, to -y
    beyond = np.column_stack([np.full(10, 10.0), -10.0 - 1.9 - np.arange(10.0), np.zeros(10)])
    x, y, lane, _ = _joined(turn, beyond)
    assert len(x) == 40 and np.array_equal(x[:30], turn[:, 0]) and np.array_equal(y[:30], turn[:, 1])
    assert join_cut(1.9, 0.0) == 0.0 and join_cut(0.3, 0.5) == 2.0 * 2.0 - 0.3 and join_cut(0.0, 3.0) == 20.0
    # a lane change's diagonal (route_spans: 3.2 m over 9 m) is left as it is
    assert join_cut(9.0, 3.2) == 0.0


def test_a_blend_replaces_only_the_straight_end_of_the_path_never_a_bend():
    """Munich: a hairpin left turn whose last lane ends 4.3 m beside the next road asked for a 20 m blend. Cut
    back through two short lanes into the 130-degree turn before them, the diagonal left the turn across its
    inner curb (3 curb hits in 600 s). A diagonal lies inside the lanes it leaves only where they run
    straight: the bend is kept whole and the blend replaces the straight after it."""
    radius, angle = 6.0, math.radians(130.0)
    t = np.linspace(0.0, angle, 15)
    bend = np.column_stack([radius * np.sin(t), radius - radius * np.cos(t)])  # left, from heading 0
    heading = np.array([math.cos(angle), math.sin(angle)])
    straight = bend[-1] + np.arange(1.0, 7.0)[:, None] * heading  # 6 m on after the bend
    before = np.column_stack([np.arange(-20.0, 0.0, 1.0), np.zeros(20)])
    path = np.concatenate([before, bend, straight])
    left = np.array([-heading[1], heading[0]])
    start = path[-1] - 0.3 * heading + 4.3 * left  # 0.3 m behind the end, 4.3 m to its side
    beyond = start + np.arange(0.0, 15.0)[:, None] * np.array([math.cos(angle + 0.6), math.sin(angle + 0.6)])
    assert join_cut(*join_gap(path[-1], angle, start)) == pytest.approx(20.3)
    zeros = np.zeros((len(path), 1))
    x, y, lane, s = _joined(np.hstack([path, zeros]), np.hstack([beyond, np.zeros((15, 1))]))
    kept = np.column_stack([x[lane == 0], y[lane == 0]])
    assert np.array_equal(kept, path[:len(kept)])
    # the bend is driven but for its last metres, which lie within JOIN_BOW of the chord the blend replaces
    assert len(kept) >= len(before) + len(bend) - 2
    chord = path[-1] - kept[-1]
    rel = path[len(kept) - 1:] - kept[-1]
    assert np.abs(chord[0] * rel[:, 1] - chord[1] * rel[:, 0]).max() / np.hypot(*chord) <= JOIN_BOW
    along = np.r_[0.0, np.cumsum(np.hypot(*np.diff(path, axis=0).T))]
    assert 6.0 <= straight_cut(path, along, 20.3) < 8.0
    # on a straight path the full cut is kept (a lane merging into its neighbour)
    line = np.column_stack([np.arange(0.0, 40.0), np.zeros(40)])
    assert straight_cut(line, line[:, 0], 20.3) == 20.3 and JOIN_BOW < 0.5


def _drive_scripted_path(dt: float, seconds: float = 20.0) -> np.ndarray:
    """The PID car (planner, controllers, dynamics) on a fixed path -- straight, a 3.5 m lane change over 20 m,
    a 12 m radius quarter turn -- stepped every ``dt``: (t, x, y) from the start."""
    from twin.planning.local_planner import LocalPlanner
    from twin.vehicle.dynamics import BicycleModel, BicycleState

    x = np.arange(0.0, 20.0, 0.5)
    turn = np.arange(0.0, math.pi / 2, 0.5 / 12.0)
    plan = np.concatenate([
        np.column_stack([np.arange(0.0, 30.0, 0.5), np.zeros(60)]),
        np.column_stack([30.0 + x, 1.75 * (1.0 - np.cos(math.pi * x / 20.0))]),
        np.column_stack([50.0 + np.arange(0.0, 30.0, 0.5), np.full(60, 3.5)]),
        np.column_stack([80.0 + 12.0 * np.sin(turn), 3.5 + 12.0 * (1.0 - np.cos(turn))]),
        np.column_stack([np.full(80, 92.0), 15.5 + np.arange(0.0, 40.0, 0.5)]),
    ])
    buffer = PathBuffer(1)
    buffer.assign(0, iter([PathChunk(np.column_stack([plan, np.zeros(len(plan))]), np.full(len(plan), 14.0),
                                     np.zeros(len(plan), dtype=np.int64))]))
    planner = LocalPlanner(buffer, PidLateral(1, dt), MODEL_S, 1, dt)
    model = BicycleModel(MODEL_S)
    state = BicycleState.at(0.0, 0.0, 0.0, 8.0)
    out = [(0.0, 0.0, 0.0)]
    for k in range(1, round(seconds / dt) + 1):
        control = planner.control(state)
        state = model.step(state, control.steer, control.throttle, control.brake, dt)
        out.append((k * dt, float(state.x[0]), float(state.y[0])))
    return np.array(out)


def _path_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Largest distance from a point of either path to the other path (a polyline through its points)."""
    from shapely import LineString, Point

    lines = LineString(a[:, 1:]), LineString(b[:, 1:])
    return max(max(lines[1].distance(Point(p)) for p in a[:, 1:]), max(lines[0].distance(Point(p)) for p in b[:, 1:]))


@pytest.mark.parametrize("dt", [0.0125, 0.1])
def test_the_pid_car_takes_the_same_path_at_any_step(dt):
    """The controllers work in seconds (the integral window, the derivative, the steering's slew rate), so a
    finer or coarser step drives the same line: within 2.5 cm of the 20 Hz drive (with per-step figures, as
    CARLA's 20 Hz controller has them, 4 to 5 cm), and to the same place."""
    reference, drive = _drive_scripted_path(0.05), _drive_scripted_path(dt)
    assert _path_distance(reference, drive) < 0.025
    assert np.hypot(*(reference[-1, 1:] - drive[-1, 1:])) < 0.05  # both stopped at the end of the path
