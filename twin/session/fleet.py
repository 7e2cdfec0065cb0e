"""The twin's own vehicles (vehicle 0 is the ego): bicycle model + pybullet bodies + path buffer + planner.

Each ``step`` controls, moves and grounds every vehicle at once, then applies the rules of the road the
simulation enforces: a wheel that jumps up a curb or a box that touches a static solid (curb, building,
object) stops the car and is logged as a collision; a stopped-by-collision, lost (more than ``lost_m`` off
its path) or stuck car is reset onto its path and counted; after a collision it is reset past the obstacle.
A car that has stopped at the end of a path which goes on after a turnaround or restart (random routes on
networks without closed loops) is moved onto the path's next part at rest, and counted as a turnaround or a
restart, not as a reset (docs/twin.md, "Routes").
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from twin.planning.buffer import PathBuffer
from twin.planning.local_planner import ControlOutput, LocalPlanner
from twin.vehicle.body import CURB_STEP, Ground, VehicleBodies
from twin.vehicle.dynamics import BicycleModel, BicycleState, stopped

OBSTACLE_SKIP_M = 8.0  # a car that hit something on its path is reset this far ahead (> a car length)
BREAK_MARGIN_M = 2.0  # a car this close to the end of its path, nearly stopped, has arrived at a route break


@dataclass(frozen=True)
class Collision:
    t: float
    vehicle: int
    kind: str  # "curb", "solid" or whatever a hook reports
    other: str
    x: float
    y: float
    detail: str = ""


@dataclass(frozen=True)
class Jump:
    """A car moved from the end of its path to the next part of its route (a turnaround or a restart)."""

    t: float
    vehicle: int
    kind: str  # "turnaround" or "restart"
    x0: float
    y0: float
    x1: float
    y1: float


@dataclass
class FleetCounters:
    resets: np.ndarray
    collisions: list[Collision] = field(default_factory=list)
    stuck_seconds: np.ndarray | None = None
    jumps: list[Jump] = field(default_factory=list)

    def count_jumps(self, kind: str, vehicle: int | None = None) -> int:
        return sum(1 for j in self.jumps if j.kind == kind and (vehicle is None or j.vehicle == vehicle))


class Fleet:
    def __init__(self, model: BicycleModel, bodies: VehicleBodies, buffer: PathBuffer, planner: LocalPlanner,
                 dt: float, solid_ids: frozenset[int] = frozenset(), body_names: dict[int, str] | None = None,
                 lost_m: float = 4.0, stuck_s: float = 20.0):
        self.model = model
        self.bodies = bodies
        self.buffer = buffer
        self.planner = planner
        self.dt = dt
        self.solid_ids = solid_ids
        self.body_names = body_names or {}
        self.lost_m = lost_m
        self.stuck_s = stuck_s
        n = len(bodies.body_ids)
        self.count = n
        self.counters = FleetCounters(np.zeros(n, dtype=np.int64), stuck_seconds=np.zeros(n))
        self.state: BicycleState | None = None
        self.ground: Ground | None = None
        self.control: ControlOutput | None = None
        self._fresh = np.ones(n, dtype=bool)  # no curb check right after a (re)placement

    # ------------------------------------------------------------------ placement
    def place_on_paths(self, mask: np.ndarray | None = None) -> None:
        """Put vehicles (all, or the masked ones) at rest on their path at their current projection."""
        b = self.buffer
        n = self.count
        mask = np.ones(n, dtype=bool) if mask is None else mask
        rows = np.arange(n)
        i = np.minimum(b.base, np.maximum(b.count - 2, 0))
        heading = np.arctan2(b.y[rows, i + 1] - b.y[rows, i], b.x[rows, i + 1] - b.x[rows, i])
        fresh = BicycleState.at(b.x[rows, i], b.y[rows, i], heading, 0.0)
        self.state = fresh if self.state is None else self.state.take(mask, fresh)
        self.bodies.reset_heights(b.z[rows, i], mask)
        self.planner.reset(mask)
        self._fresh |= mask
        self.ground = self.bodies.ground(self.state.x, self.state.y, self.state.yaw, b.z[rows, i])
        self.bodies.place(self.state.x, self.state.y, self.state.yaw, self.ground)

    # ------------------------------------------------------------------ stepping
    def step(self, t: float, speed_cap: np.ndarray | None = None) -> None:
        self.buffer.refill_all()
        control = self.planner.control(self.state, speed_cap)
        self.control = control
        previous_wheels = self.ground.wheel_z
        state = self.model.step(self.state, control.steer, control.throttle, control.brake, self.dt,
                                pitch=self.ground.pitch)
        ground = self.bodies.ground(state.x, state.y, state.yaw, control.projection.z)
        self.bodies.place(state.x, state.y, state.yaw, ground)
        jump = (ground.wheel_z - previous_wheels > CURB_STEP) & ground.wheel_hit
        jump[self._fresh] = False
        self._fresh[:] = False
        if np.any(jump):
            # a curb is an edge, not a slope: look along the wheel's travel for the rise within CURB_RUN
            before = self.bodies.wheel_xy(self.state.x, self.state.y, self.state.yaw)
            after = self.bodies.wheel_xy(state.x, state.y, state.yaw)
            for i, wheel in zip(*np.nonzero(jump)):
                jump[i, wheel] = self.bodies.steepest_rise(before[i, wheel], after[i, wheel],
                                                           float(previous_wheels[i, wheel])) > CURB_STEP
        curb = np.any(jump, axis=1)
        hit = curb.copy()
        for i in np.flatnonzero(curb):
            wheel = int(np.argmax(np.where(jump[i], ground.wheel_z[i] - previous_wheels[i], -np.inf)))
            body = int(ground.wheel_body[i, wheel])
            self._log(t, int(i), "curb", self.body_names.get(body, f"body {body}"), state,
                      f"wheel {wheel} up {ground.wheel_z[i, wheel] - previous_wheels[i, wheel]:.2f} m")
        if self.solid_ids:
            for i in range(self.count):
                if hit[i]:
                    continue
                touching = self.bodies.touching(i, self.solid_ids)
                if touching:
                    body, depth = touching[0]
                    hit[i] = True
                    self._log(t, i, "solid", self.body_names.get(body, f"body {body}"), state,
                              f"penetration {depth:.2f} m")
        if np.any(hit):
            state = stopped(state, hit)
        self.state, self.ground = state, ground
        counters = self.counters
        moving_wanted = control.target_speed > 1.0
        counters.stuck_seconds = np.where(moving_wanted & (state.speed < 0.1), counters.stuck_seconds + self.dt, 0.0)
        lost = np.abs(control.projection.lateral) > self.lost_m
        reset = hit | lost | (counters.stuck_seconds > self.stuck_s)
        if np.any(reset):
            # an obstacle on the path would stop a car put back at the same spot again, step after step
            self.buffer.skip(hit, OBSTACLE_SKIP_M)
            counters.resets += reset
            counters.stuck_seconds = np.where(reset, 0.0, counters.stuck_seconds)
            self.place_on_paths(reset)
        arrived = self.buffer.at_break(control.projection.s, BREAK_MARGIN_M) & (state.speed < 0.5) & ~reset
        if np.any(arrived):
            self._jump(t, arrived)

    def _jump(self, t: float, mask: np.ndarray) -> None:
        """Move the masked cars, stopped at the end of their paths, onto their routes' next parts."""
        before = self.state
        kinds = {int(i): self.buffer.jump(int(i)) for i in np.flatnonzero(mask)}
        self.place_on_paths(mask)
        for i, kind in kinds.items():
            self.counters.jumps.append(Jump(float(t), i, kind, float(before.x[i]), float(before.y[i]),
                                            float(self.state.x[i]), float(self.state.y[i])))

    def record_collision(self, t: float, vehicle: int, kind: str, other: str, detail: str = "") -> None:
        self._log(t, vehicle, kind, other, self.state, detail)

    def _log(self, t, i, kind, other, state, detail):
        self.counters.collisions.append(Collision(float(t), int(i), kind, other, float(state.x[i]),
                                                  float(state.y[i]), detail))
