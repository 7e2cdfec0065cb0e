"""Vehicles as kinematic pybullet boxes: wheel heights from downward rays, pitch/roll from them, contacts.

The bicycle model moves the car in the plane; this module puts it on the collision world. Each step casts
one ray per wheel (all vehicles in one ``rayTestBatch``) from above the last contact height, so a car on a
bridge deck finds the deck and a car under it finds the road below. The box never takes part in the
dynamics (mass 0); rays ignore it (its collision mask is 0), and collisions with static solids are found
with a broad-phase AABB query followed by exact ``getClosestPoints`` on the few candidates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pybullet as pb

from twin.vehicle.params import VehicleParams

RAY_ABOVE = 1.2  # m above the last wheel height: more than any curb or ramp step in one step, less than a deck
RAY_BELOW = 4.0
CURB_STEP = 0.08  # m: a wheel that rises more than this within CURB_RUN of its travel has met a curb
# m: ...a rise that steep (40 degrees and more) is an edge: the faces of curbs, raised lanes and junction
# curbs are vertical. The same rise over a longer run is ground: a steep street at speed, or a junction whose
# connecting roads disagree in height (Town07: 0.6 m apart where their footprints overlap by 1.5 m)
CURB_RUN = 0.1
PROBE_STEP = 0.05  # m between the rays that look for the edge along a wheel's travel
VEHICLE_GROUP = 0x40  # collision filter group of vehicle boxes; their mask 0 makes rays pass through them


@dataclass(frozen=True, eq=False)
class Ground:
    """Per vehicle: centre height, pitch (nose up), roll (left up), and the four wheel results."""

    z: np.ndarray
    pitch: np.ndarray
    roll: np.ndarray
    wheel_z: np.ndarray  # (n, 4): front-left, front-right, rear-left, rear-right
    wheel_hit: np.ndarray  # (n, 4) bool
    wheel_body: np.ndarray  # (n, 4) int, -1 without a hit
    centre_body: np.ndarray  # (n,) int: the body under the centre of gravity, -1 for none


def quaternions(yaw, pitch, roll) -> np.ndarray:
    """(n, 4) xyzw quaternions of body frames with heading ``yaw``, nose-up ``pitch`` and left-up ``roll``."""
    # nose up is a negative rotation about the body's left (y) axis
    cy, sy = np.cos(0.5 * yaw), np.sin(0.5 * yaw)
    cp, sp = np.cos(-0.5 * pitch), np.sin(-0.5 * pitch)
    cr, sr = np.cos(0.5 * roll), np.sin(0.5 * roll)
    return np.column_stack([
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
        cr * cp * cy + sr * sp * sy,
    ])


class VehicleBodies:
    """N vehicle boxes in one pybullet client."""

    def __init__(self, client_id: int, params: VehicleParams, count: int, colours=None, origin=(0.0, 0.0, 0.0),
                 world=None):
        self.client_id = client_id
        # the session's SimWorld: covered around the cars before their queries (streamed tiles), and the
        # translator of pybullet ids into world ids; None: the client's ids as they are
        self.world = world
        # map (OpenDRIVE local) coordinates of pybullet's (0, 0, 0): the collision world is recentred there
        self.origin = np.asarray(origin, dtype=float)
        self.params = params
        p = params
        self.box_half = np.array([0.5 * p.length, 0.5 * p.width, 0.5 * (p.height - p.ground_clearance)])
        shape = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=self.box_half.tolist(), physicsClientId=client_id)
        self.body_ids: list[int] = []
        for i in range(count):
            colour = (colours[i] if colours is not None else ((0.8, 0.1, 0.1, 1.0) if i == 0 else (0.2, 0.3, 0.8, 1)))
            visual = pb.createVisualShape(pb.GEOM_BOX, halfExtents=self.box_half.tolist(), rgbaColor=colour,
                                          physicsClientId=client_id)
            body = pb.createMultiBody(0.0, shape, visual, basePosition=[0, 0, -1000.0 - 10 * i],
                                      physicsClientId=client_id)
            pb.setCollisionFilterGroupMask(body, -1, VEHICLE_GROUP, 0, physicsClientId=client_id)
            self.body_ids.append(body)
        lf, lr, half_track = p.cg_to_front_axle, p.cg_to_rear_axle, 0.5 * p.track
        # wheel contact points in the body frame, relative to the centre of gravity
        self.wheel_offsets = np.array([[lf, half_track], [lf, -half_track], [-lr, half_track], [-lr, -half_track]])
        self._last_wheel_z: np.ndarray | None = None

    def wheel_xy(self, x, y, yaw) -> np.ndarray:
        """(n, 4, 2) plan positions of the wheels."""
        c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
        ox, oy = self.wheel_offsets[:, 0][None, :], self.wheel_offsets[:, 1][None, :]
        return np.stack([x[:, None] + c * ox - s * oy, y[:, None] + s * ox + c * oy], axis=-1)

    def reset_heights(self, z_hint: np.ndarray, mask: np.ndarray | None = None) -> None:
        """Forget the last wheel heights (after a reset); rays then start from ``z_hint`` (e.g. the lane height)."""
        hint = np.repeat(np.asarray(z_hint, dtype=float)[:, None], 4, axis=1)
        if self._last_wheel_z is None or mask is None:
            self._last_wheel_z = hint
        else:
            self._last_wheel_z = np.where(mask[:, None], hint, self._last_wheel_z)

    def ground(self, x, y, yaw, z_hint) -> Ground:
        """Cast the wheel rays and fit the body to the four contacts (missing contacts keep their last height)."""
        n = len(x)
        if self.world is not None:
            self.world.cover(np.column_stack([x, y]))
        if self._last_wheel_z is None:
            self.reset_heights(z_hint)
        last = self._last_wheel_z
        # rays 0..4n-1: the wheels; 4n..5n-1: the centre of gravity (on which surface is the car?)
        plan = np.concatenate([self.wheel_xy(x, y, yaw).reshape(-1, 2), np.column_stack([x, y])]) - self.origin[:2]
        local_last = np.concatenate([last.reshape(-1), last.mean(axis=1)]) - self.origin[2]
        top = np.column_stack([plan, local_last + RAY_ABOVE])
        bottom = np.column_stack([plan, local_last - RAY_BELOW])
        results = pb.rayTestBatch(top.tolist(), bottom.tolist(), collisionFilterMask=~VEHICLE_GROUP & 0xFFFF,
                                  physicsClientId=self.client_id)
        bodies = np.fromiter((r[0] for r in results), dtype=np.int64, count=len(results))
        if self.world is not None:
            bodies = self.world.world_ids(bodies)
        body = bodies[: 4 * n].reshape(n, 4)
        hit_z = np.fromiter((r[3][2] for r in results[: 4 * n]), dtype=float, count=4 * n).reshape(n, 4)
        hit_z += self.origin[2]
        hit = body >= 0
        wheel_z = np.where(hit, hit_z, last)
        self._last_wheel_z = wheel_z
        p = self.params
        front, rear = wheel_z[:, :2].mean(axis=1), wheel_z[:, 2:].mean(axis=1)
        left, right = wheel_z[:, [0, 2]].mean(axis=1), wheel_z[:, [1, 3]].mean(axis=1)
        pitch = np.arctan2(front - rear, p.wheelbase)
        roll = np.arctan2(left - right, p.track)
        # height of the plane through the axle midpoints at the centre of gravity
        z = rear + (front - rear) * (p.cg_to_rear_axle / p.wheelbase)
        return Ground(z, pitch, roll, wheel_z, hit, body, bodies[4 * n:])

    def steepest_rise(self, start: np.ndarray, end: np.ndarray, z_from: float) -> float:
        """The largest rise (m) of the ground within ``CURB_RUN`` along the plan segment ``start`` -> ``end``
        (map coordinates), rays cast down from ``RAY_ABOVE`` over ``z_from`` as the wheels' are."""
        length = float(np.hypot(*(np.asarray(end) - np.asarray(start))))
        count = max(int(np.ceil(length / PROBE_STEP)), 1) + 1
        plan = np.linspace(start, end, count) - self.origin[:2]
        z = z_from - self.origin[2]
        top = np.column_stack([plan, np.full(count, z + RAY_ABOVE)])
        bottom = np.column_stack([plan, np.full(count, z - RAY_BELOW)])
        results = pb.rayTestBatch(top.tolist(), bottom.tolist(), collisionFilterMask=~VEHICLE_GROUP & 0xFFFF,
                                  physicsClientId=self.client_id)
        heights = np.array([r[3][2] for r in results if r[0] >= 0])
        if len(heights) < 2:
            return 0.0
        reach = max(int(round(CURB_RUN / (length / (count - 1) if length > 0 else CURB_RUN))), 1)
        reach = min(reach, len(heights) - 1)
        return float(max(np.max(heights[k:] - heights[:-k]) for k in range(1, reach + 1)))

    def place(self, x, y, yaw, ground: Ground) -> None:
        """Move the boxes: bottom face at ground clearance above the fitted plane, centred on the bounding box."""
        p = self.params
        q = quaternions(yaw, ground.pitch, ground.roll)
        c, s = np.cos(yaw), np.sin(yaw)
        cp, sp = np.cos(ground.pitch), np.sin(ground.pitch)
        forward = p.cg_to_body_centre
        up = p.ground_clearance + self.box_half[2]
        ox, oy, oz = self.origin
        cx = x + c * (forward * cp - up * sp) - ox
        cy = y + s * (forward * cp - up * sp) - oy
        cz = ground.z + forward * sp + up * cp - oz
        for i, body in enumerate(self.body_ids):
            pb.resetBasePositionAndOrientation(body, (cx[i], cy[i], cz[i]), q[i].tolist(),
                                               physicsClientId=self.client_id)

    def touching(self, index: int, candidates: frozenset[int] | set[int]) -> list[tuple[int, float]]:
        """(body id, penetration depth m) of the candidate bodies the box of vehicle ``index`` touches (ids of
        the world's when a world is given: ``candidates`` and the answer)."""
        body = self.body_ids[index]
        low, high = pb.getAABB(body, physicsClientId=self.client_id)
        near = pb.getOverlappingObjects(low, high, physicsClientId=self.client_id) or ()
        found = []
        for other, _link in near:
            key = other if self.world is None else self.world.world_id(other)
            if key not in candidates:
                continue
            points = pb.getClosestPoints(body, other, 0.0, physicsClientId=self.client_id)
            if points:
                found.append((key, float(-min(point[8] for point in points))))
        return found
