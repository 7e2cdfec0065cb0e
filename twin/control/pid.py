"""CARLA's VehiclePIDController, vectorised over N vehicles, in a right-handed frame (positive steer = left).

Defaults are CARLA LocalPlanner's: lateral K_P=1.95, K_I=0.05, K_D=0.2; longitudinal K_P=1.0, K_I=0.05,
K_D=0; max throttle 0.75, max brake 0.3, max steering 0.8. As in CARLA the longitudinal error is in km/h and
the lateral error is the signed angle between the heading and the line to the target waypoint.

CARLA runs its controller at a fixed 20 Hz: the integral is the sum of the last 10 errors times dt = 1/20 and
the steering changes by at most 0.1 per step. Here the controllers take the simulation's step ``dt`` (``twin
drive --dt``) and keep CARLA's figures in seconds, so a finer or coarser step does not change how the car
drives: the integral covers the last ``INTEGRAL_WINDOW_S`` = 0.5 s (10 errors at dt = 1/20), the derivative is
per second, and the steering slews at most ``max_steer_rate`` = 2.0 per second (0.1 per step at 1/20).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

INTEGRAL_WINDOW_S = 0.5  # CARLA's 10-error window at its 20 Hz


@dataclass(frozen=True)
class PidGains:
    k_p: float
    k_i: float
    k_d: float


CARLA_LATERAL = PidGains(1.95, 0.05, 0.2)
CARLA_LONGITUDINAL = PidGains(1.0, 0.05, 0.0)


class PidTerm:
    """One PID for N vehicles stepped every ``dt`` seconds, its integral over CARLA's 0.5 s window (the last
    round(0.5 / dt) errors); ``reset(mask)`` clears the masked windows."""

    def __init__(self, gains: PidGains, count: int, dt: float):
        if not (dt > 0 and np.isfinite(dt)):
            raise ValueError(f"the controller's dt must be a positive number of seconds, not {dt!r}")
        self.gains = gains
        self.dt = float(dt)
        self.window = max(2, round(INTEGRAL_WINDOW_S / self.dt))
        self.errors = np.zeros((count, self.window))
        self.filled = np.zeros(count, dtype=np.int64)

    def reset(self, mask: np.ndarray | None = None) -> None:
        mask = np.ones(len(self.filled), dtype=bool) if mask is None else mask
        self.errors[mask] = 0.0
        self.filled[mask] = 0

    def __call__(self, error: np.ndarray) -> np.ndarray:
        g = self.gains
        self.errors = np.roll(self.errors, -1, axis=1)
        self.errors[:, -1] = error
        self.filled = np.minimum(self.filled + 1, self.window)
        ready = self.filled >= 2
        derivative = np.where(ready, (self.errors[:, -1] - self.errors[:, -2]) / self.dt, 0.0)
        integral = np.where(ready, self.errors.sum(axis=1) * self.dt, 0.0)
        return np.clip(g.k_p * error + g.k_d * derivative + g.k_i * integral, -1.0, 1.0)


def heading_error(x, y, yaw, target_x, target_y) -> np.ndarray:
    """Signed angle (rad) from the heading to the direction of the target point; positive = target on the left."""
    fx, fy = np.cos(yaw), np.sin(yaw)
    wx, wy = target_x - x, target_y - y
    return np.arctan2(fx * wy - fy * wx, fx * wx + fy * wy)


class PidLateral:
    name = "pid"

    def __init__(self, count: int, dt: float, gains: PidGains = CARLA_LATERAL, base_lookahead: float = 3.0,
                 lookahead_per_speed: float = 0.5):
        self.term = PidTerm(gains, count, dt)
        # CARLA LocalPlanner: the target waypoint is the first one further than 3.0 m + 0.5 s * speed
        self.base_lookahead = base_lookahead
        self.lookahead_per_speed = lookahead_per_speed

    def lookahead(self, speed: np.ndarray) -> np.ndarray:
        return self.base_lookahead + self.lookahead_per_speed * speed

    def reset(self, mask=None) -> None:
        self.term.reset(mask)

    def steer(self, x, y, yaw, speed, target_x, target_y, params) -> np.ndarray:
        return self.term(heading_error(x, y, yaw, target_x, target_y))


class PidLongitudinal:
    def __init__(self, count: int, dt: float, gains: PidGains = CARLA_LONGITUDINAL):
        self.term = PidTerm(gains, count, dt)

    def reset(self, mask=None) -> None:
        self.term.reset(mask)

    def __call__(self, speed: np.ndarray, target_speed: np.ndarray) -> np.ndarray:
        """Acceleration command in [-1, 1] (negative = brake) from speeds in m/s (CARLA works in km/h)."""
        return self.term(3.6 * (target_speed - speed))


@dataclass(frozen=True)
class ActuatorLimits:
    max_throttle: float = 0.75
    max_brake: float = 0.3
    max_steering: float = 0.8
    max_steer_rate: float = 2.0  # steer command units per second (CARLA: 0.1 per step at 20 Hz)


CARLA_LIMITS = ActuatorLimits()


def split_acceleration(acceleration: np.ndarray, limits: ActuatorLimits) -> tuple[np.ndarray, np.ndarray]:
    """(throttle, brake) from a signed command, as CARLA's VehiclePIDController does."""
    throttle = np.where(acceleration >= 0.0, np.minimum(acceleration, limits.max_throttle), 0.0)
    brake = np.where(acceleration < 0.0, np.minimum(-acceleration, limits.max_brake), 0.0)
    return throttle, brake


def limit_steering(steer: np.ndarray, previous: np.ndarray, limits: ActuatorLimits, dt: float,
                   max_steering: np.ndarray | float | None = None) -> np.ndarray:
    """Steering within the limits' rate over a step of ``dt`` seconds, and within +-``max_steering`` (default:
    the limits' own)."""
    bound = limits.max_steering if max_steering is None else max_steering
    change = limits.max_steer_rate * dt
    steer = np.clip(steer, previous - change, previous + change)
    return np.clip(steer, -bound, bound)
