"""A spinning lidar from pybullet ray casts: ``channels`` x ``columns`` rays per scan, at ``rate_hz``.

Directions are fixed in the sensor frame and rotated with the car each scan; pybullet's batch limit
(16,383 rays per call) splits a 32 x 1024 scan into four calls, each spread over Bullet's worker threads.
Vehicle boxes of the twin are not hit by rays (their collision mask), so the ego never sees itself.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pybullet as pb

BATCH = 8192  # pybullet answers at most 16,383 rays per call


@dataclass(frozen=True)
class LidarConfig:
    channels: int = 32
    columns: int = 1024
    rate_hz: float = 10.0
    range_m: float = 100.0
    lower_fov_deg: float = -25.0
    upper_fov_deg: float = 15.0
    mount_height: float = 1.9  # m above the ground under the centre of gravity


@dataclass(frozen=True, eq=False)
class LidarScan:
    t: float
    ranges: np.ndarray  # (channels, columns) metres, inf without a hit
    points: np.ndarray  # (n, 3) hit points in the map frame
    bodies: np.ndarray  # (n,) pybullet body id of each hit


class LidarSensor:
    def __init__(self, client_id: int, config: LidarConfig, dt: float, threads: int = 0, origin=(0.0, 0.0, 0.0),
                 embree=None, world=None):
        self.client_id = client_id
        # the session's SimWorld: hit body ids are reported as its world ids (streamed tiles are renumbered
        # by pybullet); the cars' ground query has covered the lidar's range around the ego already
        self.world = world
        self.embree = embree  # an EmbreeWorld: the static world is cast with Embree, other bodies in pybullet
        self.ignore_ids: frozenset[int] = frozenset()  # bodies rays never hit (the twin's own cars)
        self.origin = np.asarray(origin, dtype=float)  # map coordinates of pybullet's (0, 0, 0)
        self.config = config
        self.threads = threads
        self.every = max(round(1.0 / (config.rate_hz * dt)), 1)
        elevation = np.radians(np.linspace(config.lower_fov_deg, config.upper_fov_deg, config.channels))
        azimuth = np.linspace(0.0, 2.0 * np.pi, config.columns, endpoint=False)
        el, az = np.meshgrid(elevation, azimuth, indexing="ij")
        self.directions = np.column_stack([(np.cos(el) * np.cos(az)).ravel(), (np.cos(el) * np.sin(az)).ravel(),
                                           np.sin(el).ravel()])

    def due(self, step: int) -> bool:
        return step % self.every == 0

    def scan(self, t: float, x: float, y: float, z: float, yaw: float, pitch: float = 0.0,
             roll: float = 0.0) -> LidarScan:
        c = self.config
        rotation = _rotation(yaw, pitch, roll)
        sensor = np.array([x, y, z]) - self.origin + rotation @ np.array([0.0, 0.0, c.mount_height])
        if self.embree is not None:
            from twin.sensors.embree import dynamic_hits

            directions = self.directions @ rotation.T
            ranges, bodies = self.embree.first_hits(sensor, directions, c.range_m)
            dynamic_hits(self.client_id, self.embree.static_ids | self.ignore_ids, sensor, directions, c.range_m,
                         ranges, bodies)
            hit = np.isfinite(ranges)
            points = sensor + self.origin + directions[hit] * ranges[hit][:, None]
            return LidarScan(t, ranges.reshape(c.channels, c.columns), points, self._world_ids(bodies[hit]))
        ends = sensor + (self.directions @ rotation.T) * c.range_m
        fractions = np.empty(len(ends))
        bodies = np.empty(len(ends), dtype=np.int64)
        start = [sensor.tolist()] * min(BATCH, len(ends))
        for lo in range(0, len(ends), BATCH):
            part = ends[lo:lo + BATCH]
            results = pb.rayTestBatch(start[:len(part)], part.tolist(), numThreads=self.threads,
                                      physicsClientId=self.client_id)
            bodies[lo:lo + len(part)] = [r[0] for r in results]
            fractions[lo:lo + len(part)] = [r[2] for r in results]
        hit = bodies >= 0
        ranges = np.where(hit, fractions * c.range_m, np.inf).reshape(c.channels, c.columns)
        points = sensor + self.origin + self.directions[hit] @ rotation.T * (fractions[hit] * c.range_m)[:, None]
        return LidarScan(t, ranges, points, self._world_ids(bodies[hit]))

    def _world_ids(self, bodies: np.ndarray) -> np.ndarray:
        return bodies if self.world is None else self.world.world_ids(bodies)


def _rotation(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """Body -> map rotation for heading ``yaw``, nose-up ``pitch``, left-up ``roll``."""
    cy, sy, cp, sp, cr, sr = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch), np.cos(roll), np.sin(roll)
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    ry = np.array([[cp, 0, -sp], [0, 1, 0], [sp, 0, cp]])  # nose up
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    return rz @ ry @ rx
