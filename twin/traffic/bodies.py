"""SUMO vehicles and persons as kinematic pybullet boxes, and the ego's contacts with them.

Each actor is a mass-0 box sized from its vType (length x width x height), moved every step with
``resetBasePositionAndOrientation`` (skipped while its pose does not change); it shows in ray casts (lidar, camera) and can be asked for contacts.
Actors that left SUMO are removed from pybullet the same step. Contacts with the ego come from pybullet's
own narrow phase (``getClosestPoints`` at distance 0), asked only for actors whose bounding circles overlap
the ego's -- a handful of calls per step whatever the traffic.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pybullet as pb

from twin.traffic.sumo import Actors

VEHICLE_RGBA = (0.85, 0.55, 0.1, 1.0)
PERSON_RGBA = (0.2, 0.4, 0.95, 1.0)
_SHAPE_ROUNDING_M = 0.01  # boxes that differ by less than a centimetre share one collision shape


@dataclass(frozen=True)
class Contact:
    actor: str  # SUMO id
    is_person: bool
    depth_m: float  # penetration (positive)
    x: float  # contact point, local frame
    y: float


class TrafficBodies:
    """The pybullet side of SUMO traffic in one client; ``origin`` is the world's shift (local - origin)."""

    def __init__(self, client_id: int, origin=(0.0, 0.0, 0.0)) -> None:
        self.client_id = client_id
        self.origin = np.asarray(origin, dtype=float)
        self.body_of: dict[str, int] = {}
        self._half: dict[str, np.ndarray] = {}
        self._pose: dict[str, list[float]] = {}  # the pose pybullet has: x, y, z, qz, qw
        self._shapes: dict[tuple, tuple[int, int]] = {}
        self.created = 0
        self.removed = 0

    def _shape(self, half: tuple[float, float, float], person: bool) -> tuple[int, int]:
        key = (*half, person)
        shape = self._shapes.get(key)
        if shape is None:
            collision = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=half, physicsClientId=self.client_id)
            visual = pb.createVisualShape(pb.GEOM_BOX, halfExtents=half, rgbaColor=PERSON_RGBA if person else
                                          VEHICLE_RGBA, physicsClientId=self.client_id)
            shape = self._shapes[key] = (collision, visual)
        return shape

    def update(self, actors: Actors) -> None:
        """Create boxes for new actors, move all, remove those that are gone."""
        present = set(actors.ids)
        for actor in [a for a in self.body_of if a not in present]:
            pb.removeBody(self.body_of.pop(actor), physicsClientId=self.client_id)
            self._half.pop(actor, None)
            self._pose.pop(actor, None)
            self.removed += 1
        if not len(actors):
            return
        centre = actors.centre - self.origin
        half_yaw = 0.5 * actors.yaw
        # one conversion to Python floats for all actors (tolist), not three float() calls per actor
        poses = np.column_stack([centre, np.sin(half_yaw), np.cos(half_yaw)]).tolist()
        last = self._pose
        for i, (actor, pose) in enumerate(zip(actors.ids, poses)):
            if last.get(actor) == pose:  # standing still (queues, red lights): pybullet already has it
                continue
            last[actor] = pose
            body = self.body_of.get(actor)
            position = (pose[0], pose[1], pose[2])
            orientation = (0.0, 0.0, pose[3], pose[4])
            if body is None:
                half = tuple(round(0.5 * float(v) / _SHAPE_ROUNDING_M) * _SHAPE_ROUNDING_M
                             for v in (actors.length[i], actors.width[i], actors.height[i]))
                collision, visual = self._shape(half, bool(actors.is_person[i]))
                body = pb.createMultiBody(baseMass=0.0, baseCollisionShapeIndex=collision,
                                          baseVisualShapeIndex=visual, basePosition=position,
                                          baseOrientation=orientation, physicsClientId=self.client_id)
                self.body_of[actor] = body
                self._half[actor] = np.array(half)
                self.created += 1
            else:
                pb.resetBasePositionAndOrientation(body, position, orientation, physicsClientId=self.client_id)

    def contacts(self, ego_body: int, ego_xy: tuple[float, float], ego_radius_m: float,
                 actors: Actors) -> list[Contact]:
        """Actors whose boxes touch or overlap the ego's body now (pybullet narrow phase)."""
        if not len(actors):
            return []
        centre = actors.centre
        reach = ego_radius_m + 0.5 * np.hypot(actors.length, actors.width)
        near = np.flatnonzero(np.hypot(centre[:, 0] - ego_xy[0], centre[:, 1] - ego_xy[1]) <= reach)
        found = []
        for i in near:
            body = self.body_of.get(actors.ids[i])
            if body is None:
                continue
            points = pb.getClosestPoints(ego_body, body, 0.0, physicsClientId=self.client_id)
            if not points:
                continue
            deepest = min(points, key=lambda p: p[8])
            if deepest[8] <= 0.0:
                found.append(Contact(actors.ids[i], bool(actors.is_person[i]), float(-deepest[8]),
                                     float(deepest[5][0] + self.origin[0]), float(deepest[5][1] + self.origin[1])))
        return found

    def clear(self) -> None:
        for body in self.body_of.values():
            pb.removeBody(body, physicsClientId=self.client_id)
        self.removed += len(self.body_of)
        self.body_of.clear()
        self._half.clear()
        self._pose.clear()
