"""Wheel odometry and an IMU from the vehicle state: speed, yaw rate, body accelerations, with seeded noise."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, slots=True)
class ImuSample:
    t: float
    speed: float  # m/s, wheel odometry
    yaw_rate: float  # rad/s, gyro z
    accel_x: float  # m/s^2, body forward (gravity along the slope included, as an accelerometer feels it)
    accel_y: float  # m/s^2, body left


@dataclass(frozen=True)
class ImuConfig:
    speed_sigma: float = 0.02
    gyro_sigma: float = 0.001
    accel_sigma: float = 0.02


class ImuSensor:
    def __init__(self, config: ImuConfig, rng: np.random.Generator, dt: float):
        self.config = config
        self.rng = rng
        self.dt = dt
        self._last: tuple[float, float] | None = None

    def reset(self) -> None:
        self._last = None

    def measure(self, t: float, vx: float, vy: float, yaw_rate: float, pitch: float) -> ImuSample:
        c = self.config
        last_vx, last_vy = self._last if self._last is not None else (vx, vy)
        self._last = (vx, vy)
        ax = (vx - last_vx) / self.dt - vy * yaw_rate + 9.81 * np.sin(pitch)
        ay = (vy - last_vy) / self.dt + vx * yaw_rate
        n = self.rng.standard_normal(4)
        return ImuSample(t, float(np.hypot(vx, vy) + c.speed_sigma * n[0]), float(yaw_rate + c.gyro_sigma * n[1]),
                         float(ax + c.accel_sigma * n[2]), float(ay + c.accel_sigma * n[3]))
