"""A forward camera rendered headless by pybullet's TinyRenderer (CPU, no display, no GPU)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pybullet as pb


@dataclass(frozen=True)
class CameraConfig:
    width: int = 320
    height: int = 240
    fov_deg: float = 90.0
    rate_hz: float = 5.0
    mount_forward: float = 1.0  # m ahead of the centre of gravity
    mount_height: float = 1.4
    far_m: float = 150.0


@dataclass(frozen=True, eq=False)
class CameraImage:
    t: float
    rgb: np.ndarray  # (h, w, 3) uint8


class CameraSensor:
    def __init__(self, client_id: int, config: CameraConfig, dt: float, origin=(0.0, 0.0, 0.0)):
        self.client_id = client_id
        self.origin = np.asarray(origin, dtype=float)  # map coordinates of pybullet's (0, 0, 0)
        self.config = config
        self.every = max(round(1.0 / (config.rate_hz * dt)), 1)
        c = config
        self.projection = pb.computeProjectionMatrixFOV(c.fov_deg, c.width / c.height, 0.1, c.far_m,
                                                        physicsClientId=client_id)

    def due(self, step: int) -> bool:
        return step % self.every == 0

    def capture(self, t: float, x: float, y: float, z: float, yaw: float, pitch: float = 0.0) -> CameraImage:
        c = self.config
        forward = np.array([np.cos(yaw) * np.cos(pitch), np.sin(yaw) * np.cos(pitch), np.sin(pitch)])
        eye = np.array([x, y, z + c.mount_height]) - self.origin + c.mount_forward * forward
        view = pb.computeViewMatrix(eye.tolist(), (eye + forward).tolist(), [0, 0, 1], physicsClientId=self.client_id)
        _, _, rgba, _, _ = pb.getCameraImage(c.width, c.height, view, self.projection,
                                             renderer=pb.ER_TINY_RENDERER, physicsClientId=self.client_id)
        rgb = np.asarray(rgba, dtype=np.uint8).reshape(c.height, c.width, 4)[:, :, :3]
        return CameraImage(t, rgb)
