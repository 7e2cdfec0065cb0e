"""Vehicle parameters; the default is a Tesla Model S (public spec sheet values, rounded)."""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class VehicleParams:
    length: float = 4.97
    width: float = 1.96
    height: float = 1.445
    wheelbase: float = 2.96
    front_overhang: float = 0.95  # front bumper ahead of the front axle
    track: float = 1.66
    ground_clearance: float = 0.15
    mass: float = 2100.0
    # 48/52 front/rear weight distribution puts the centre of gravity 1.54 m behind the front axle
    cg_to_front_axle: float = 1.54
    yaw_inertia: float = 4000.0  # kg m^2, about m (L^2 + W^2) / 12 times 0.8 for a low, mid-heavy car
    cornering_stiffness_front: float = 160_000.0  # N/rad per axle (linear tyre model)
    cornering_stiffness_rear: float = 180_000.0
    max_steer: float = math.radians(35.0)  # front wheel angle at steer command 1.0
    max_steer_rate: float = math.radians(180.0)  # rad/s of the wheel angle (steering actuator)
    max_drive_accel: float = 5.0  # m/s^2 at low speed
    max_drive_power: float = 310_000.0  # W, caps the acceleration at speed
    max_brake_decel: float = 9.0  # m/s^2 at brake 1.0
    drag_area: float = 0.56  # Cd * A (m^2)
    rolling_resistance: float = 0.010
    max_speed: float = 69.0  # m/s (250 km/h)

    @property
    def cg_to_rear_axle(self) -> float:
        return self.wheelbase - self.cg_to_front_axle

    @property
    def rear_overhang(self) -> float:
        return self.length - self.wheelbase - self.front_overhang

    @property
    def cg_to_body_centre(self) -> float:
        """Signed distance (forward) from the centre of gravity to the middle of the bounding box."""
        front_of_cg = self.cg_to_front_axle + self.front_overhang
        return front_of_cg - 0.5 * self.length

    @property
    def min_turn_radius(self) -> float:
        return self.wheelbase / math.tan(self.max_steer)


MODEL_S = VehicleParams()
