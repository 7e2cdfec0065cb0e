"""Waypoints on lane centre lines: ``next(d)`` branches at junctions, neighbours, lane-change permission.

A waypoint is a lane and a distance along its centre line in driving direction, like CARLA's
``carla.Waypoint`` (with ``next``, ``get_left_lane``, ``get_right_lane``, ``lane_change``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tavf_mapkit.lanegraph import LaneGraph, LaneKey
from twin.map.lanelines import LaneLines


@dataclass(frozen=True, order=True)
class Waypoint:
    key: LaneKey
    along: float


@dataclass(frozen=True)
class WaypointPose:
    x: float
    y: float
    z: float
    heading: float
    road_id: str
    lane_id: int


class WaypointMap:
    def __init__(self, graph: LaneGraph, step: float = 1.0):
        self.graph = graph
        self.lines = LaneLines(graph, step)

    def pose(self, waypoint: Waypoint) -> WaypointPose:
        point, heading = self.lines[waypoint.key].at(waypoint.along)
        return WaypointPose(float(point[0]), float(point[1]), float(point[2]), heading,
                            self.graph.road_id(waypoint.key), waypoint.key.lane_id)

    def next(self, waypoint: Waypoint, distance: float) -> list[Waypoint]:
        """Waypoints ``distance`` metres further in driving direction; one per branch at junctions."""
        length = self.lines[waypoint.key].length
        if waypoint.along + distance <= length:
            return [Waypoint(waypoint.key, waypoint.along + distance)]
        rest = waypoint.along + distance - length
        found: list[Waypoint] = []
        for successor in self.graph.successors(waypoint.key):
            found.extend(self.next(Waypoint(successor, 0.0), rest))
        return sorted(set(found))

    def _neighbour(self, waypoint: Waypoint, side: str) -> Waypoint | None:
        left, right = self.graph.neighbours(waypoint.key)
        other = left if side == "left" else right
        if other is None or other not in self.graph:
            return None
        # same road section: scale the position by the ratio of the centre-line lengths
        ratio = self.lines[other].length / max(self.lines[waypoint.key].length, 1e-9)
        return Waypoint(other, waypoint.along * ratio)

    def left(self, waypoint: Waypoint) -> Waypoint | None:
        return self._neighbour(waypoint, "left")

    def right(self, waypoint: Waypoint) -> Waypoint | None:
        return self._neighbour(waypoint, "right")

    def lane_change(self, waypoint: Waypoint) -> str:
        """CARLA's ``lane_change``: "None", "Left", "Right" or "Both"."""
        left = self.graph.lane_change_allowed(waypoint.key, "left")
        right = self.graph.lane_change_allowed(waypoint.key, "right")
        return {(False, False): "None", (True, False): "Left", (False, True): "Right"}.get((left, right), "Both")

    def generate(self, distance: float) -> list[Waypoint]:
        """Waypoints every ``distance`` metres on every lane of the graph."""
        out: list[Waypoint] = []
        for key in sorted(self.graph.keys):
            length = self.lines[key].length
            out.extend(Waypoint(key, float(a)) for a in np.arange(0.0, length + 1e-9, distance))
        return out
