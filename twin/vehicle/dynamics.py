"""A dynamic bicycle model, blended into the kinematic one at walking speed, for N vehicles at once.

Why this model (see docs/twin.md): it is deterministic to the last bit (plain numpy, fixed substeps, no
solver iterations), costs a few microseconds per vehicle, vectorises over a fleet, and its linear-tyre
dynamics give the understeer and lag a controller must cope with. Below ``blend_low`` m/s the dynamic model
is ill-conditioned (slip angles from tiny velocities), so it blends linearly into the kinematic bicycle,
which is exact there.

Frame: x east, y north, yaw counter-clockwise from +x; positive steer turns left. Velocities ``vx``/``vy``
are in the body frame at the centre of gravity.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from types import SimpleNamespace

import numpy as np

from twin.vehicle.params import VehicleParams

GRAVITY = 9.81
AIR_DENSITY = 1.2
FRICTION = 1.0  # dry asphalt; caps the lateral tyre force


@dataclass(frozen=True, eq=False)
class BicycleState:
    """Arrays of length N; ``steer`` is the actual front wheel angle (rad)."""

    x: np.ndarray
    y: np.ndarray
    yaw: np.ndarray
    vx: np.ndarray
    vy: np.ndarray
    yaw_rate: np.ndarray
    steer: np.ndarray

    @staticmethod
    def at(x, y, yaw, speed=0.0) -> BicycleState:
        x = np.atleast_1d(np.asarray(x, dtype=float)).copy()
        zeros = np.zeros_like(x)
        return BicycleState(x, np.atleast_1d(np.asarray(y, dtype=float)).copy(),
                            np.atleast_1d(np.asarray(yaw, dtype=float)).copy(),
                            np.broadcast_to(np.asarray(speed, dtype=float), x.shape).copy(),
                            zeros.copy(), zeros.copy(), zeros.copy())

    @property
    def speed(self) -> np.ndarray:
        return np.hypot(self.vx, self.vy)

    def __len__(self) -> int:
        return len(self.x)

    def take(self, mask: np.ndarray, other: BicycleState) -> BicycleState:
        """This state where ``mask`` is False, ``other`` where it is True (for resets)."""
        return BicycleState(*(np.where(mask, getattr(other, f), getattr(self, f)) for f in _FIELDS))


_FIELDS = ("x", "y", "yaw", "vx", "vy", "yaw_rate", "steer")


# The model is written once against a tiny math namespace: numpy for a fleet, the math module for one
# vehicle, where numpy's per-call overhead would cost ten times the arithmetic.
_NUMPY = SimpleNamespace(atan2=np.arctan2, cos=np.cos, sin=np.sin, tan=np.tan, minimum=np.minimum,
                         maximum=np.maximum)
_SCALAR = SimpleNamespace(atan2=math.atan2, cos=math.cos, sin=math.sin, tan=math.tan, minimum=min, maximum=max)


@dataclass(frozen=True)
class BicycleModel:
    params: VehicleParams
    substeps: int = 4
    blend_low: float = 3.0
    blend_high: float = 6.0

    def step(self, state: BicycleState, steer_cmd, throttle, brake, dt: float, pitch=0.0) -> BicycleState:
        """Advance by ``dt`` seconds with commands held; ``pitch`` (nose up, rad) adds the grade force."""
        values = [getattr(state, f) for f in _FIELDS]
        if len(state) == 1:
            scalars = [float(v[0]) for v in values]
            commands = [float(np.asarray(c).reshape(-1)[0]) for c in (steer_cmd, throttle, brake, pitch)]
            out = self._integrate(_SCALAR, *scalars, *commands, dt)
            return BicycleState(*(np.array([v]) for v in out))
        n = len(state)
        commands = [np.broadcast_to(np.asarray(c, dtype=float), (n,)) for c in (steer_cmd, throttle, brake, pitch)]
        return BicycleState(*self._integrate(_NUMPY, *values, *commands, dt))

    def _integrate(self, ns, x, y, yaw, vx, vy, r, delta, steer_cmd, throttle, brake, pitch, dt):
        p = self.params
        lf, lr, length = p.cg_to_front_axle, p.cg_to_rear_axle, p.wheelbase
        h = dt / self.substeps
        target = ns.minimum(ns.maximum(steer_cmd, -1.0), 1.0) * p.max_steer
        max_delta = p.max_steer_rate * h
        normal_front = FRICTION * p.mass * GRAVITY * lr / length
        normal_rear = FRICTION * p.mass * GRAVITY * lf / length
        throttle = ns.minimum(ns.maximum(throttle, 0.0), 1.0)
        braking = ns.minimum(ns.maximum(brake, 0.0), 1.0) * p.max_brake_decel + GRAVITY * ns.sin(pitch)
        drag = 0.5 * AIR_DENSITY * p.drag_area / p.mass
        power = p.max_drive_power / p.mass
        blend = 1.0 / (self.blend_high - self.blend_low)
        for _ in range(self.substeps):
            delta = delta + ns.minimum(ns.maximum(target - delta, -max_delta), max_delta)
            drive = throttle * ns.minimum(p.max_drive_accel, power / ns.maximum(vx, 1.0))
            # resistance fades out below 0.1 m/s so a standing car does not roll backwards
            resist = (p.rolling_resistance * GRAVITY + drag * vx * vx) * ns.minimum(vx * 10.0, 1.0)
            vx = ns.minimum(ns.maximum(vx + (drive - resist - braking) * h, 0.0), p.max_speed)
            vx_safe = ns.maximum(vx, 0.5)
            alpha_front = delta - ns.atan2(vy + lf * r, vx_safe)
            alpha_rear = -ns.atan2(vy - lr * r, vx_safe)
            force_front = ns.minimum(ns.maximum(p.cornering_stiffness_front * alpha_front, -normal_front),
                                     normal_front)
            force_rear = ns.minimum(ns.maximum(p.cornering_stiffness_rear * alpha_rear, -normal_rear), normal_rear)
            lateral_front = force_front * ns.cos(delta)
            tan_delta = ns.tan(delta)
            w = ns.minimum(ns.maximum((vx - self.blend_low) * blend, 0.0), 1.0)
            vy = (w * (vy + h * ((lateral_front + force_rear) / p.mass - vx * r))
                  + (1.0 - w) * (vx * lr * tan_delta / length))
            r = w * (r + h * (lf * lateral_front - lr * force_rear) / p.yaw_inertia) + (1.0 - w) * (vx * tan_delta / length)
            yaw = yaw + r * h
            c, s = ns.cos(yaw), ns.sin(yaw)
            x = x + (vx * c - vy * s) * h
            y = y + (vx * s + vy * c) * h
        yaw = (yaw + math.pi) % (2.0 * math.pi) - math.pi
        return x, y, yaw, vx, vy, r, delta


def stopped(state: BicycleState, mask: np.ndarray) -> BicycleState:
    """The state with the masked vehicles brought to rest where they are (a curb or wall stops them)."""
    zero = np.where(mask, 0.0, 1.0)
    return replace(state, vx=state.vx * zero, vy=state.vy * zero, yaw_rate=state.yaw_rate * zero)
