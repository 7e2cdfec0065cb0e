"""The ego in traffic: a speed cap for the next step from red lights, leaders and people on its path.

Everything is measured along the ego's planned path (``session.path_ahead``), not along SUMO's idea of
the ego's route: an actor counts when its box centre is within half a lane of the path; a stop line counts
when it lies on the path facing the same way, and of the links leaving that stop line the one whose
outgoing lane starts nearest the path is the ego's. Speeds follow Krauss' safe speed (SUMO's default car
following): the fastest speed from which the ego can still stop behind the obstacle, braking at
``decel``, after a reaction time of ``time_gap``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from twin.traffic.sumo import SignalLinks, TrafficSnapshot

STOP_STATES = frozenset("ryu")  # red, yellow, red-yellow: do not enter


@dataclass(frozen=True)
class BehaviourConfig:
    look_ahead_m: float = 80.0
    time_gap_s: float = 1.5
    min_gap_m: float = 2.5  # standstill distance to a leader or a person
    decel: float = 4.0  # m/s^2 the ego plans with (comfortable-firm)
    max_decel: float = 7.5  # beyond this a yellow light is driven through rather than braked for
    stop_margin_m: float = 1.0  # stop this far before the stop line
    corridor_m: float = 1.6  # half-width of the path corridor for vehicles (half a lane plus a bit)
    person_corridor_m: float = 2.2  # people: the car's half width plus a metre of clearance


@dataclass(frozen=True)
class SpeedCap:
    speed: float  # m/s, inf = no constraint
    reason: str  # "", "signal", "leader", "person"
    actor: str = ""
    distance_m: float = math.inf


def safe_speed(gap_m, leader_speed, decel: float, reaction_s: float) -> np.ndarray:
    """Krauss: the largest v with v*tau + v^2/(2b) <= gap + v_l^2/(2b)."""
    gap = np.maximum(np.asarray(gap_m, dtype=float), 0.0)
    vl = np.maximum(np.asarray(leader_speed, dtype=float), 0.0)
    bt = decel * reaction_s
    return np.maximum(-bt + np.sqrt(bt * bt + vl * vl + 2.0 * decel * gap), 0.0)


def project_on_path(path_xy: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(along, lateral, path heading) of points on a polyline, along = arc length from its first point."""
    if len(path_xy) < 2 or not len(points):
        return np.full(len(points), np.inf), np.full(len(points), np.inf), np.zeros(len(points))
    a, b = path_xy[:-1], path_xy[1:]
    seg = b - a
    seg_len = np.maximum(np.hypot(seg[:, 0], seg[:, 1]), 1e-9)
    start_s = np.r_[0.0, np.cumsum(seg_len)[:-1]]
    rel = points[:, None, :] - a[None, :, :]
    u = np.clip((rel * seg[None]).sum(-1) / seg_len ** 2, 0.0, 1.0)
    foot = a[None] + u[..., None] * seg[None]
    dist = np.hypot(points[:, None, 0] - foot[..., 0], points[:, None, 1] - foot[..., 1])
    best = np.argmin(dist, axis=1)
    rows = np.arange(len(points))
    along = start_s[best] + u[rows, best] * seg_len[best]
    # points behind the path's start project onto it at 0; report their true (negative) position
    first_dir = seg[0] / seg_len[0]
    behind = (best == 0) & (u[rows, 0] <= 0.0)
    along = np.where(behind, ((points - a[0]) @ first_dir), along)
    rel0 = points - a[0]
    lateral = np.where(behind, np.abs(first_dir[0] * rel0[:, 1] - first_dir[1] * rel0[:, 0]), dist[rows, best])
    return along, lateral, np.arctan2(seg[best, 1], seg[best, 0])


class EgoBehaviour:
    """Call ``cap(...)`` once per step; it also counts red-light violations as the ego crosses stop lines."""

    def __init__(self, links: SignalLinks, ego_length_m: float, ego_width_m: float,
                 config: BehaviourConfig | None = None) -> None:
        self.links = links
        self.config = config or BehaviourConfig()
        self.ego_length = ego_length_m
        self.ego_width = ego_width_m
        self.red_light_violations = 0
        self.violations: list[tuple[float, str]] = []
        self._approach: tuple[int, float] | None = None  # (link row, distance of its stop line ahead)
        self._passed: dict[int, float] = {}  # link rows the ego drove over, and when
        self.last = SpeedCap(math.inf, "")

    def cap(self, t: float, ego_xy: tuple[float, float], ego_yaw: float, ego_speed: float, path: np.ndarray,
            snapshot: TrafficSnapshot) -> SpeedCap:
        """The cap for the next step; ``ego_xy`` is the centre of the ego's box, ``path`` its planned path."""
        c = self.config
        path_xy = np.asarray(path, dtype=float)[:, :2]
        if len(path_xy) < 2:  # no path known: look straight ahead
            direction = np.array([math.cos(ego_yaw), math.sin(ego_yaw)])
            path_xy = np.asarray(ego_xy)[None] + np.outer([0.0, c.look_ahead_m], direction)
        ego_along = float(project_on_path(path_xy, np.asarray(ego_xy, dtype=float)[None])[0][0])
        caps = [SpeedCap(math.inf, "")]
        actors = snapshot.actors
        if len(actors):
            # only what can be on the next look_ahead metres of path is projected onto it
            near = np.hypot(actors.x - ego_xy[0], actors.y - ego_xy[1]) <= c.look_ahead_m + 10.0
            actors = actors.select(near) if not near.all() else actors
        if len(actors):
            along, lateral, _ = project_on_path(path_xy, actors.centre[:, :2])
            along = along - ego_along
            gap = along - 0.5 * self.ego_length - 0.5 * actors.length - c.min_gap_m
            corridor = np.where(actors.is_person, c.person_corridor_m, c.corridor_m + 0.5 * actors.width)
            ahead = (along > 0.0) & (lateral <= corridor) & (along <= c.look_ahead_m)
            for i in np.flatnonzero(ahead):
                person = bool(actors.is_person[i])
                # people and crossing traffic are obstacles at rest; a leader moves on at its own speed
                leader_speed = 0.0 if person else float(actors.speed[i]) * max(
                    0.0, math.cos(float(actors.yaw[i]) - ego_yaw))
                speed = float(safe_speed(gap[i], leader_speed, c.decel, c.time_gap_s))
                caps.append(SpeedCap(speed, "person" if person else "leader", actors.ids[i], float(along[i])))
        caps.append(self._signal_cap(t, ego_along, ego_speed, path_xy, snapshot.signal_state))
        self.last = min(caps, key=lambda cap: cap.speed)
        return self.last

    def _signal_cap(self, t, ego_along, ego_speed, path_xy, state) -> SpeedCap:
        c = self.config
        links = self.links
        if not len(links):
            return SpeedCap(math.inf, "")
        along = np.full(len(links), np.inf)
        lateral = np.full(len(links), np.inf)
        heading = np.zeros(len(links))
        origin = path_xy[0]
        near = np.flatnonzero(np.hypot(links.stop_x - origin[0], links.stop_y - origin[1]) <= c.look_ahead_m + 20.0)
        if self._approach is not None:
            near = np.union1d(near, [self._approach[0]])
        along[near], lateral[near], heading[near] = project_on_path(
            path_xy, np.column_stack([links.stop_x[near], links.stop_y[near]]))
        # distance from the ego's front bumper to each stop line, along the path
        ahead = along - ego_along - 0.5 * self.ego_length
        self._count_violation(t, ahead, state)
        facing = np.cos(links.stop_yaw - heading) > math.cos(math.radians(40.0))
        passed = np.zeros(len(links), dtype=bool)
        passed[[row for row, when in self._passed.items() if t - when < 30.0]] = True
        on_path = (ahead > 0.0) & (ahead <= c.look_ahead_m) & (lateral <= 1.5) & facing & ~passed
        if not on_path.any():
            self._approach = None
            return SpeedCap(math.inf, "")
        first = np.flatnonzero(on_path & (ahead <= ahead[on_path].min() + 0.5))  # links of the nearest stop line
        _, out_lateral, _ = project_on_path(path_xy, np.column_stack([links.out_x[first], links.out_y[first]]))
        row = int(first[np.argmin(out_lateral)])
        distance = float(ahead[row])
        self._approach = (row, distance)
        if state[row] not in STOP_STATES:
            return SpeedCap(math.inf, "")
        room = distance - c.stop_margin_m
        if state[row] == "y" and ego_speed * ego_speed > 2.0 * c.max_decel * max(room, 0.0):
            return SpeedCap(math.inf, "")  # too close to stop for yellow: go
        # the same reaction time as behind a leader: the controller needs time to turn a cap into braking
        return SpeedCap(float(safe_speed(room, 0.0, c.decel, c.time_gap_s)), "signal", links.tls_id[row], distance)

    def _count_violation(self, t, ahead, state) -> None:
        """A violation: the front bumper crossed the stop line of the link the ego approached while it was red."""
        if self._approach is None or not len(state):
            return
        row, before = self._approach
        if before > 0.0 >= ahead[row] > -10.0:
            self._passed[row] = t
            self._approach = None
            if state[row] == "r":
                self.red_light_violations += 1
                self.violations.append((t, self.links.tls_id[row]))
