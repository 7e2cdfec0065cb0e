"""Replaying a session recording: kinematically (the recorded states as they were) or by re-simulation.

Re-simulation runs the drive again from the recorded configuration -- same map (checked by its sha256),
seed, options -- with the recorded UDM answers delivered at the steps they arrived instead of asking a
server, and compares every recorded ego state with the new one, field by field. The twin is deterministic
(fixed step, seeded generators, deterministic pybullet settings), so anything but zero difference is a bug
or a changed input, and the report says at which step the two drives parted.
"""

from __future__ import annotations

import math
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from tavf_mapkit.errors import InputError
from twin.recording.reader import Recording, read_recording
from twin.recording.writer import RECORDING_NAME

STATE_FIELDS = ("x", "y", "z", "yaw", "speed", "pitch", "roll", "lat", "lon", "steer", "throttle", "brake")
IDENTITY_FIELDS = ("t", "step", "road_id", "lane_id")
CONFIG_ONLY_KEYS = ("map_sha256", "map_name")  # added by the session to the options, not options themselves
TRAJECTORY_COLUMNS = ("t", "step", "x", "y", "z", "yaw", "speed", "lat", "lon", "road_id", "lane_id")


def trajectory_rows(recording: Recording) -> Iterator[dict[str, Any]]:
    """The recorded ego states in step order (what a kinematic replay shows)."""
    states = recording.ego_states
    if not states:
        raise InputError("the recording has no ego states (/ego/state); is it a twin drive recording?",
                         file=str(recording.path))
    yield from states


def format_row(state: dict[str, Any]) -> str:
    """One CSV line; floats with ``repr`` so the printed trajectory is the recorded one, exactly."""
    return ",".join(_text(state.get(column)) for column in TRAJECTORY_COLUMNS)


def _text(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return repr(value)
    text = str(value)
    return f'"{text}"' if "," in text or '"' in text else text


@dataclass(frozen=True)
class Comparison:
    """How a re-simulated drive compares with the recorded one."""

    steps_recorded: int
    steps_resimulated: int
    steps_compared: int
    max_difference: dict[str, float]  # per state field, absolute
    first_difference_step: int | None  # first step where any field differs, None when identical
    mismatched_identity: dict[str, int]  # IDENTITY_FIELDS that differ: how many steps
    recording_complete: bool
    # /traffic (SUMO vehicles, persons, signals, the ego's cap): 10 Hz messages, compared whole
    traffic_recorded: int = 0
    traffic_resimulated: int = 0
    traffic_mismatched: int = 0  # compared messages that differ in any value
    traffic_first_difference_step: int | None = None

    @property
    def identical(self) -> bool:
        def as_many(recorded: int, resimulated: int) -> bool:
            return resimulated == recorded or (not self.recording_complete and resimulated >= recorded)

        return (as_many(self.steps_recorded, self.steps_resimulated) and self.first_difference_step is None
                and not self.mismatched_identity and self.steps_compared > 0
                and as_many(self.traffic_recorded, self.traffic_resimulated) and not self.traffic_mismatched)

    def as_dict(self) -> dict[str, Any]:
        data = {f.name: getattr(self, f.name) for f in fields(self)}
        data["identical"] = self.identical
        data["max_difference_overall"] = max(self.max_difference.values(), default=0.0)
        return data


def compare_states(recorded: list[dict[str, Any]], resimulated: list[dict[str, Any]],
                   recording_complete: bool = True) -> Comparison:
    n = min(len(recorded), len(resimulated))
    max_difference = dict.fromkeys(STATE_FIELDS, 0.0)
    mismatched: dict[str, int] = {}
    first = None
    for index in range(n):
        a, b = recorded[index], resimulated[index]
        differs = False
        for name in STATE_FIELDS:
            difference = _difference(a.get(name), b.get(name))
            if difference:
                differs = True
                max_difference[name] = max(max_difference[name], difference)
        for name in IDENTITY_FIELDS:
            if a.get(name) != b.get(name):
                differs = True
                mismatched[name] = mismatched.get(name, 0) + 1
        if differs and first is None:
            first = int(a.get("step", index))
    return Comparison(len(recorded), len(resimulated), n, max_difference, first, mismatched, recording_complete)


def with_traffic(comparison: Comparison, recorded: list[dict[str, Any]],
                 resimulated: list[dict[str, Any]]) -> Comparison:
    """The comparison with the /traffic messages compared one by one (the first ``len(recorded)``)."""
    from dataclasses import replace

    differing = [a.get("step") for a, b in zip(recorded, resimulated) if a != b]
    return replace(comparison, traffic_recorded=len(recorded), traffic_resimulated=len(resimulated),
                   traffic_mismatched=len(differing),
                   traffic_first_difference_step=differing[0] if differing else None)


def _difference(a: Any, b: Any) -> float:
    if a == b:
        return 0.0
    if a is None or b is None:
        return math.inf
    difference = abs(float(a) - float(b))
    return difference if math.isfinite(difference) else math.inf


def drive_config_from(recording: Recording, map_dir: Path | None = None, out_dir: Path | None = None):
    """The ``DriveConfig`` and plugin options of the recorded drive, checked against the map on disk."""
    from twin.session.config import DriveConfig
    from twin.sim.build import Build

    recorded = recording.config.get("config")
    if not isinstance(recorded, dict) or "map" not in recorded:
        raise InputError("the recording has no drive configuration (/config)", file=str(recording.path))
    build = Build.open(map_dir if map_dir is not None else recorded["map"])
    expected = recorded.get("map_sha256")
    if expected and build.map_sha256 != expected:
        raise InputError(f"the map differs from the recorded one (sha256 {build.map_sha256[:12]}... vs recorded "
                         f"{expected[:12]}...); pass --map with the build the drive used", file=str(build.xodr))
    known = {f.name for f in fields(DriveConfig)} - {"plugins"}
    values = {key: value for key, value in recorded.items() if key in known}
    plugins = {key: value for key, value in recorded.items() if key not in known and key not in CONFIG_ONLY_KEYS}
    values["map"] = build.path
    values["out"] = out_dir if out_dir is not None else Path(recorded.get("out") or "resim-out")
    if values.get("route"):
        values["route"] = Path(values["route"])
        if not values["route"].is_file():
            raise InputError("the recorded route trace is not there any more", file=str(values["route"]))
    if values.get("gnss_bias") is not None:
        values["gnss_bias"] = tuple(values["gnss_bias"])
    values["gui"] = False
    values["plot"] = False
    values["pace"] = None  # re-simulate as fast as possible; pacing never changes the states
    plugins["record"] = True  # the re-simulation's own recording is what gets compared
    if plugins.get("udm"):
        plugins["udm_replay"] = str(recording.path)  # recorded answers at their steps, no server
    return DriveConfig(**values, plugins=plugins)


def resimulate(path: str | Path, map_dir: Path | None = None, keep: Path | None = None) -> Comparison:
    """Drive the recording again and compare the ego states and the traffic; ``keep`` keeps the new outputs."""
    from twin.session.loop import Session
    from twin.session.plugins import create_hooks

    recording = read_recording(path)
    recorded_states = list(trajectory_rows(recording))
    with tempfile.TemporaryDirectory(prefix="twin-resim-") as scratch:
        out_dir = keep if keep is not None else Path(scratch) / "resim"
        config = drive_config_from(recording, map_dir, out_dir)
        if not recording.complete:
            # A drive cut short: re-run just as far as it got.
            last_t = float(recorded_states[-1]["t"])
            config = _replace(config, duration=max(last_t, config.dt))
        Session(config, create_hooks(config.as_dict())).run()
        again = read_recording(out_dir / RECORDING_NAME)
    comparison = compare_states(recorded_states, again.ego_states, recording.complete)
    return with_traffic(comparison, _traffic(recording), _traffic(again))


def _traffic(recording: Recording) -> list[dict[str, Any]]:
    from twin.traffic.record import TRAFFIC_CHANNEL

    return [message.data for message in recording.messages(TRAFFIC_CHANNEL.topic)]


def _replace(config, **changes):
    from dataclasses import replace

    return replace(config, **changes)
