"""The local planner: from the path buffer and the vehicle state to steer, throttle and brake (N vehicles).

Target point: the path point ``controller.lookahead(speed)`` metres ahead of the projection (CARLA picks
the first waypoint further than 3 m + 0.5 s x speed). Target speed: the route's speed (limit, recording or
``--speed``), capped so every tighter bend and the route's end ahead can be reached braking at ``decel``,
and by any cap the session passes (hooks: red lights, leaders). Steering: the limits' rate and range, except
that below ``FULL_LOCK_SPEED`` the wheel may turn to full lock.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from twin.control.pid import CARLA_LIMITS, ActuatorLimits, PidLongitudinal, limit_steering, split_acceleration
from twin.planning.buffer import PathBuffer, Projection
from twin.vehicle.dynamics import BicycleState
from twin.vehicle.params import VehicleParams


@dataclass(frozen=True, eq=False)
class ControlOutput:
    steer: np.ndarray
    throttle: np.ndarray
    brake: np.ndarray
    target_speed: np.ndarray
    projection: Projection


FULL_LOCK_SPEED = 5.0  # m/s (18 km/h): below it the steering may go past max_steering to full lock


class LocalPlanner:
    def __init__(self, buffer: PathBuffer, lateral, params: VehicleParams, count: int, dt: float,
                 limits: ActuatorLimits = CARLA_LIMITS, decel: float = 2.0):
        self.buffer = buffer
        self.lateral = lateral
        self.dt = dt  # the simulation's step: the speed PID and the steering rate are per second
        self.longitudinal = PidLongitudinal(count, dt)
        self.params = params
        self.limits = limits
        self.decel = decel
        self.previous_steer = np.zeros(count)

    def reset(self, mask: np.ndarray) -> None:
        self.lateral.reset(mask)
        self.longitudinal.reset(mask)
        self.previous_steer = np.where(mask, 0.0, self.previous_steer)

    def control(self, state: BicycleState, speed_cap: np.ndarray | None = None) -> ControlOutput:
        buffer = self.buffer
        projection = buffer.project(state.x, state.y)
        speed = state.speed
        target_speed = buffer.allowed_speed(projection.s, self.decel)
        if speed_cap is not None:
            target_speed = np.minimum(target_speed, speed_cap)
        tx, ty = buffer.point_at(projection.s + self.lateral.lookahead(speed))
        steer = self.lateral.steer(state.x, state.y, state.yaw, speed, tx, ty, self.params)
        # at junction speed a driver turns the wheel to full lock: CARLA's 0.8 limit (a 5.6 m radius) made the
        # car swing out of 100-125 degree junction turns onto the curb; the full 35 degrees turn it in 4.2 m
        bound = np.where(speed < FULL_LOCK_SPEED, 1.0, self.limits.max_steering)
        steer = limit_steering(steer, self.previous_steer, self.limits, self.dt, bound)
        self.previous_steer = steer
        throttle, brake = split_acceleration(self.longitudinal(speed, target_speed), self.limits)
        # hold a stopped car with the full brake, as a driver would at the end of a route
        hold = (target_speed < 0.05) & (speed < 0.5)
        brake = np.where(hold, 1.0, brake)
        throttle = np.where(hold, 0.0, throttle)
        return ControlOutput(steer, throttle, brake, target_speed, projection)
