"""Traffic in the session recording: one JSON message per 10 Hz tick on ``/traffic`` (docs/traffic.md)."""

from __future__ import annotations

from typing import Any

import numpy as np

from twin.recording.schemas import Channel

TRAFFIC = {"title": "twin.Traffic", "type": "object",
           "description": "SUMO vehicles and persons (local frame, box centres), signal states and the ego's cap",
           "required": ["t", "step", "ids", "x", "y", "yaw", "speed", "signals"]}
TRAFFIC_CHANNEL = Channel("/traffic", TRAFFIC)


def traffic_message(snapshot, cap) -> dict[str, Any]:
    actors = snapshot.actors
    centre = actors.centre
    # rounded and turned into Python numbers column by column (numpy), not value by value
    return {
        "t": snapshot.time, "step": snapshot.step, "ids": list(actors.ids),
        "person": actors.is_person.tolist(),
        "x": np.round(centre[:, 0], 3).tolist(), "y": np.round(centre[:, 1], 3).tolist(),
        "z": np.round(centre[:, 2], 3).tolist(), "yaw": np.round(actors.yaw, 4).tolist(),
        "speed": np.round(actors.speed, 3).tolist(),
        "length": actors.length.tolist(), "width": actors.width.tolist(),
        "signals": "".join(snapshot.signal_state.tolist()),
        "ego_cap": {"speed": None if cap.speed == float("inf") else round(cap.speed, 3), "reason": cap.reason,
                    "actor": cap.actor},
    }
