"""The Model S bicycle model and its pybullet body: kinematics, grounding on slopes, curbs and walls."""

from __future__ import annotations

import math

import numpy as np
import pybullet as pb
import pytest

from twin.control.purepursuit import PurePursuit
from twin.planning.buffer import PathBuffer
from twin.planning.chunks import PathChunk
from twin.planning.local_planner import LocalPlanner
from twin.session.fleet import Fleet
from twin.vehicle.body import VehicleBodies, quaternions
from twin.vehicle.dynamics import BicycleModel, BicycleState
from twin.vehicle.params import MODEL_S

DT = 0.05


def test_model_s_dimensions():
    assert (MODEL_S.length, MODEL_S.width, MODEL_S.wheelbase, MODEL_S.mass) == (4.97, 1.96, 2.96, 2100.0)
    assert math.degrees(MODEL_S.max_steer) == pytest.approx(35.0)
    assert MODEL_S.front_overhang + MODEL_S.wheelbase + MODEL_S.rear_overhang == pytest.approx(MODEL_S.length)


def test_slow_turn_follows_the_kinematic_circle():
    """Below the blend speed the model is the kinematic bicycle: the CG circles at R = lr / sin(beta)."""
    model = BicycleModel(MODEL_S)
    state = BicycleState.at([0.0], [0.0], [0.0], [2.0])
    steer = 0.5
    for _ in range(400):  # hold speed with a little throttle against rolling resistance
        state = model.step(state, steer, 0.02, 0.0, DT)
    delta = steer * MODEL_S.max_steer
    beta = math.atan(MODEL_S.cg_to_rear_axle * math.tan(delta) / MODEL_S.wheelbase)
    radius = MODEL_S.cg_to_rear_axle / math.sin(beta)
    assert float(state.speed[0] / abs(state.yaw_rate[0])) == pytest.approx(radius, rel=1e-6)


def test_straight_acceleration_and_braking():
    model = BicycleModel(MODEL_S)
    state = BicycleState.at([0.0], [0.0], [0.3], [0.0])
    for _ in range(100):
        state = model.step(state, 0.0, 1.0, 0.0, DT)
    assert 15.0 < state.speed[0] < 5.0 * 5.0  # at most max_drive_accel for 5 s
    assert float(state.y[0] / state.x[0]) == pytest.approx(math.tan(0.3), rel=1e-9)  # no drift sideways
    for _ in range(200):
        state = model.step(state, 0.0, 0.0, 1.0, DT)
    assert state.speed[0] == 0.0  # braking stops the car and never reverses it


def test_scalar_and_fleet_paths_agree_to_the_last_bit():
    model = BicycleModel(MODEL_S)
    one = BicycleState.at([1.0], [2.0], [0.1], [12.0])
    many = BicycleState.at([1.0, 1.0, 1.0], [2.0, 2.0, 2.0], [0.1, 0.1, 0.1], [12.0, 12.0, 12.0])
    for k in range(300):
        steer = 0.3 * math.sin(k / 20)
        one = model.step(one, steer, 0.2, 0.0, DT)
        many = model.step(many, steer, 0.2, 0.0, DT)
    for field in ("x", "y", "yaw", "vx", "vy", "yaw_rate", "steer"):
        assert np.all(getattr(many, field) == getattr(one, field)[0]), field


def test_uphill_grade_slows_the_car():
    model = BicycleModel(MODEL_S)
    flat = up = BicycleState.at([0.0], [0.0], [0.0], [10.0])
    for _ in range(40):
        flat = model.step(flat, 0.0, 0.0, 0.0, DT)
        up = model.step(up, 0.0, 0.0, 0.0, DT, pitch=math.radians(6.0))
    assert up.speed[0] < flat.speed[0] - 9.81 * math.sin(math.radians(6.0)) * 2.0 * 0.99


def test_quaternion_convention_matches_pybullet():
    yaw, pitch, roll = 0.7, 0.1, -0.05
    q = quaternions(np.array([yaw]), np.array([pitch]), np.array([roll]))[0]
    matrix = np.array(pb.getMatrixFromQuaternion(q.tolist())).reshape(3, 3)
    forward = matrix[:, 0]
    assert forward[2] == pytest.approx(math.sin(pitch))  # nose up
    assert math.atan2(forward[1], forward[0]) == pytest.approx(yaw)
    assert matrix[:, 1][2] == pytest.approx(math.sin(roll) * math.cos(pitch), abs=1e-9)  # left side up


@pytest.fixture
def client():
    cid = pb.connect(pb.DIRECT)
    plane = pb.createMultiBody(0, pb.createCollisionShape(pb.GEOM_PLANE, physicsClientId=cid), physicsClientId=cid)
    yield cid, plane
    pb.disconnect(cid)


def _box(cid, centre, half, yaw=0.0, pitch=0.0):
    shape = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=half, physicsClientId=cid)
    q = pb.getQuaternionFromEuler([0.0, -pitch, yaw])
    return pb.createMultiBody(0, shape, basePosition=centre, baseOrientation=q, physicsClientId=cid)


def _straight_fleet(cid, length=120.0, speed=8.0, solids=frozenset()):
    buffer = PathBuffer(1)
    xs = np.arange(0.0, length, 1.0)
    points = np.column_stack([xs, np.zeros_like(xs), np.zeros_like(xs)])
    buffer.assign(0, iter([PathChunk(points, np.full(len(xs), speed), np.zeros(len(xs), dtype=np.int64))]))
    planner = LocalPlanner(buffer, PurePursuit(1), MODEL_S, 1, DT)
    bodies = VehicleBodies(cid, MODEL_S, 1, origin=(0.0, 0.0, 0.0))
    fleet = Fleet(BicycleModel(MODEL_S), bodies, buffer, planner, DT, solids, {b: f"body {b}" for b in solids})
    fleet.place_on_paths()
    return fleet


def _ramp(cid, degrees: float, start: float = 20.0) -> None:
    """A ramp starting at x = ``start``: a long thin box tilted up by ``degrees``, its top surface meeting z = 0."""
    angle = math.radians(degrees)
    half = [40.0, 5.0, 0.25]
    centre_x = start + half[0] * math.cos(angle) + half[2] * math.sin(angle)
    centre_z = half[0] * math.sin(angle) - half[2] * math.cos(angle)
    _box(cid, [centre_x, 0.0, centre_z], half, pitch=angle)


def test_the_car_climbs_a_ramp_and_sits_on_it(client):
    cid, _ = client
    start, angle = 20.0, math.radians(5.0)
    _ramp(cid, 5.0, start)
    fleet = _straight_fleet(cid)
    for step in range(1, 200):
        fleet.step(step * DT)
        if fleet.state.x[0] > start + 12.0:
            break
    x = float(fleet.state.x[0])
    assert fleet.ground.pitch[0] == pytest.approx(angle, abs=1e-3)
    expected = (x - start) * math.tan(angle)  # height of the ramp surface under the centre of gravity
    assert fleet.ground.z[0] == pytest.approx(expected, abs=0.01)
    assert fleet.counters.collisions == [] and fleet.counters.resets[0] == 0


def test_a_curb_stops_the_car_and_is_logged(client):
    cid, _ = client
    _box(cid, [40.0, -1.0, 0.075], [5.0, 3.0, 0.075])  # a 15 cm step across the path
    fleet = _straight_fleet(cid)
    for step in range(1, 200):
        fleet.step(step * DT)
        if fleet.counters.collisions:
            break
    hit = fleet.counters.collisions[0]
    assert hit.kind == "curb" and hit.vehicle == 0
    # the front wheels (1.54 m ahead of the centre of gravity) reach the step at x = 35 within one step
    assert 35.0 - MODEL_S.cg_to_front_axle - 0.5 < hit.x < 35.0 - MODEL_S.cg_to_front_axle + 0.5
    assert fleet.counters.resets[0] == 1


def test_a_car_reset_after_a_hit_goes_on_past_the_obstacle(client):
    """A wall across the path is hit once; the reset puts the car beyond it, not back in front of it forever."""
    cid, _ = client
    wall = _box(cid, [50.0, 0.0, 1.5], [0.2, 5.0, 1.5])
    fleet = _straight_fleet(cid, solids=frozenset({wall}))
    for step in range(1, 400):
        fleet.step(step * DT)
    assert [c.kind for c in fleet.counters.collisions] == ["solid"]
    assert fleet.counters.resets[0] == 1 and fleet.state.x[0] > 60.0


def test_a_wall_is_a_solid_collision(client):
    cid, _ = client
    wall = _box(cid, [50.0, 0.0, 1.5], [0.2, 5.0, 1.5])
    fleet = _straight_fleet(cid, solids=frozenset({wall}))
    kinds = []
    for step in range(1, 300):
        fleet.step(step * DT)
        kinds += [c.kind for c in fleet.counters.collisions]
        if kinds:
            break
    hit = fleet.counters.collisions[0]
    assert hit.kind in ("solid", "curb") and hit.x < 50.0 - 0.2
    # a wall 3 m high is higher than the 1.2 m the wheel rays look above the road: it is the box that hits it
    assert hit.kind == "solid" and hit.other == f"body {wall}"
