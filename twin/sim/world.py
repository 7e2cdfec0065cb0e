"""The pybullet client of a session: deterministic settings and the build's collision world.

The collision world is loaded exactly as mapkit wrote it, with ``tavf_mapkit.world.load``; its ``origin``
(the map coordinates of pybullet's (0, 0, 0)) is kept so every pybullet call converts map <-> pybullet.
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


class SimWorld:
    def __init__(self, build: Build, dt: float, gui: bool = False):
        if not build.collision_world.is_file():
            raise InputError("the build has no collision world (collision/world.json); rebuild it with "
                             "`mapkit build` and the collision stage", file=str(build.path))
        self.build = build
        self.client_id = _connect(gui)
        try:
            pb.resetSimulation(physicsClientId=self.client_id)
            # deterministic broad phase; nothing sleeps; one fixed step (the vehicle model substeps itself)
            pb.setPhysicsEngineParameter(fixedTimeStep=dt, numSubSteps=1, deterministicOverlappingPairs=1,
                                         physicsClientId=self.client_id)
            pb.setGravity(0.0, 0.0, -9.81, physicsClientId=self.client_id)
            from tavf_mapkit.world import load

            self.bodies = load(build.path, self.client_id)
        except BaseException:
            self.close()
            raise
        self.origin = np.asarray(self.bodies.origin, dtype=float)
        self.solid_ids, self.body_names = _classify(self.bodies)

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
