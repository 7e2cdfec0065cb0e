"""Pure pursuit: steer the rear axle onto a circle through a look-ahead point on the path."""

from __future__ import annotations

import numpy as np


class PurePursuit:
    name = "pure-pursuit"

    def __init__(self, count: int, base_lookahead: float = 2.5, lookahead_per_speed: float = 0.45,
                 max_lookahead: float = 25.0):
        self.base_lookahead = base_lookahead
        self.lookahead_per_speed = lookahead_per_speed
        self.max_lookahead = max_lookahead

    def lookahead(self, speed: np.ndarray) -> np.ndarray:
        """Distance of the target point ahead of the centre of gravity, along the path."""
        return np.minimum(self.base_lookahead + self.lookahead_per_speed * speed, self.max_lookahead)

    def reset(self, mask=None) -> None:
        pass

    def steer(self, x, y, yaw, speed, target_x, target_y, params) -> np.ndarray:
        """Steer command in [-1, 1]: wheel angle atan(2 L sin(alpha) / l_d) over the maximum wheel angle."""
        c, s = np.cos(yaw), np.sin(yaw)
        rear_x, rear_y = x - params.cg_to_rear_axle * c, y - params.cg_to_rear_axle * s
        dx, dy = target_x - rear_x, target_y - rear_y
        forward = c * dx + s * dy
        left = -s * dx + c * dy
        distance_sq = np.maximum(forward * forward + left * left, 1e-6)
        # curvature of the circle through the rear axle and the target: 2 sin(alpha) / l_d = 2 left / l_d^2
        curvature = 2.0 * left / distance_sq
        return np.arctan(params.wheelbase * curvature) / params.max_steer
