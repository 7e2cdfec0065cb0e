"""Traffic in the session recording: one JSON message per 10 Hz tick on ``/traffic`` (docs/traffic.md)."""

from __future__ import annotations

from typing import Any

from twin.recording.schemas import Channel

TRAFFIC = {"title": "twin.Traffic", "type": "object",
           "description": "SUMO vehicles and persons (local frame, box centres), signal states and the ego's cap",
           "required": ["t", "step", "ids", "x", "y", "yaw", "speed", "signals"]}
TRAFFIC_CHANNEL = Channel("/traffic", TRAFFIC)


def traffic_message(snapshot, cap) -> dict[str, Any]:
    actors = snapshot.actors
    centre = actors.centre
    return {
        "t": snapshot.time, "step": snapshot.step, "ids": list(actors.ids),
        "person": [bool(v) for v in actors.is_person],
        "x": [round(float(v), 3) for v in centre[:, 0]], "y": [round(float(v), 3) for v in centre[:, 1]],
        "z": [round(float(v), 3) for v in centre[:, 2]], "yaw": [round(float(v), 4) for v in actors.yaw],
        "speed": [round(float(v), 3) for v in actors.speed],
        "length": [float(v) for v in actors.length], "width": [float(v) for v in actors.width],
        "signals": "".join(snapshot.signal_state.tolist()),
        "ego_cap": {"speed": None if cap.speed == float("inf") else round(cap.speed, 3), "reason": cap.reason,
                    "actor": cap.actor},
    }
