"""The pybullet client of a session: deterministic settings and the build's collision world.

The collision world is the one mapkit wrote, either streamed around the cars (``tavf_mapkit.world.TileStream``:
the tiles within ``reach_m`` + ``CAR_REACH_M`` of a car, a region's start and memory do not grow with the map)
or loaded whole (``tavf_mapkit.world.load``, for the GUI, where a person looks at the map). Bodies are named
by their world id (their index in world.json, the pybullet id a whole load gives them) in ``solid_ids``,
``body_names``, ``bodies`` and every body id the vehicles and sensors report (``world_ids`` translates pybullet's
ids): a streamed drive is the same drive as a whole-world one, see docs/twin.md. The ``origin`` (the map
coordinates of pybullet's (0, 0, 0)) is kept so every pybullet call converts map <-> pybullet.
"""

from __future__ import annotations

import logging

import numpy as np
import pybullet as pb

from tavf_mapkit.errors import InputError
from twin.sim.build import Build

log = logging.getLogger(__name__)

# body groups of the collision world that stop a car when its box touches them. The others are surfaces
# (road, roadside) and curbs: a body overhangs a curb as high as its ground clearance, the wheels find curbs.
SOLID_GROUPS = frozenset({"object", "signal", "building"})

# m from a car's centre of gravity that its own queries reach, with room: the wheel rays (~3 m), the curb probe
# along a wheel's last step, the box's bounding box (half diagonal ~2.6 m). Streamed tiles cover this plus the
# sensors' reach around every car.
CAR_REACH_M = 10.0


def sensor_reach(lidar: bool, camera: bool) -> float:
    """How far (m) the session's sensors see from the car: the lidar's range; the camera's far plane at the
    corners of its view (``fov_deg`` is vertical, as pybullet's projection takes it)."""
    from twin.sensors.camera import CameraConfig
    from twin.sensors.lidar import LidarConfig

    reach = [0.0]
    if lidar:
        reach.append(LidarConfig().range_m)
    if camera:
        c = CameraConfig()
        tan_v = np.tan(np.radians(0.5 * c.fov_deg))
        reach.append(float(c.far_m * np.sqrt(1.0 + tan_v ** 2 * (1.0 + (c.width / c.height) ** 2))) + c.mount_forward)
    return max(reach)


class SimWorld:
    """``stream``: load tiles around the cars (``cover``) instead of the whole world; ``reach_m``: how far the
    sensors reach from a car (``sensor_reach``)."""

    def __init__(self, build: Build, dt: float, gui: bool = False, stream: bool = False, reach_m: float = 0.0):
        if not build.collision_world.is_file():
            raise InputError("the build has no collision world (collision/world.json); rebuild it with "
                             "`mapkit build` and the collision stage", file=str(build.path))
        self.build = build
        self.stream = None
        self.client_id = _connect(gui)
        try:
            pb.resetSimulation(physicsClientId=self.client_id)
            # deterministic broad phase; nothing sleeps; one fixed step (the vehicle model substeps itself)
            pb.setPhysicsEngineParameter(fixedTimeStep=dt, numSubSteps=1, deterministicOverlappingPairs=1,
                                         physicsClientId=self.client_id)
            pb.setGravity(0.0, 0.0, -9.81, physicsClientId=self.client_id)
            from tavf_mapkit.world import TileStream, load

            if stream:
                self.stream = TileStream(build.path, self.client_id, radius=float(reach_m) + CAR_REACH_M)
                self.bodies = self.stream.catalogue
            else:
                self.stream = None
                self.bodies = load(build.path, self.client_id)
        except BaseException:
            self.close()
            raise
        self.origin = np.asarray(self.bodies.origin, dtype=float)
        self.solid_ids, self.body_names = _classify(self.bodies)

    def cover(self, points_local) -> None:
        """Make the world complete around these car positions ((n, 2) OpenDRIVE local x, y): called before
        every query of the cars (their rays and contacts); nothing to do for a whole world."""
        if self.stream is not None:
            self.stream.cover(points_local)

    def world_ids(self, pybullet_ids) -> np.ndarray:
        """World ids of pybullet body ids (-1 stays -1); a whole world's ids are its pybullet ids."""
        if self.stream is not None:
            return self.stream.world_ids(pybullet_ids)
        return np.asarray(pybullet_ids, dtype=np.int64)

    def world_id(self, pybullet_id: int) -> int:
        return self.stream.world_id(pybullet_id) if self.stream is not None else pybullet_id

    def close(self) -> None:
        if self.client_id is not None and pb.isConnected(self.client_id):
            pb.disconnect(self.client_id)
        self.client_id = None


def _connect(gui: bool) -> int:
    if gui:
        try:
            return pb.connect(pb.GUI)
        except pb.error:
            log.warning("no display for the pybullet GUI; running headless")
    return pb.connect(pb.DIRECT)


def _classify(bodies) -> tuple[frozenset[int], dict[int, str]]:
    """(ids of solid bodies a car must not touch, a readable name per body id) from the loaded world."""
    solid = frozenset(body.body_id for body in bodies.bodies if body.group in SOLID_GROUPS)
    names = {body.body_id: f"{body.group} {body.name}" for body in bodies.bodies}
    return solid, names
