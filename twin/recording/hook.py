"""The recording hook: every ``twin drive`` writes ``DIR/session.mcap`` (unless ``--no-record``).

What goes in (docs/recording.md): the full configuration once, the exact ego state and its Foxglove pose and
transform every step, each GNSS fix as ``foxglove.LocationFix``, and -- from the UDM hook, through
``twin.recording.bus`` -- every UDM answer (exact, for ``twin replay --resimulate``), its latency, and the
objects as a ``foxglove.SceneUpdate`` and a ``foxglove.GeoJSON``. metrics.json goes in at the end.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from twin import __version__
from twin.recording import bus
from twin.recording.messages import ego_pose, ego_state, ego_transform, location_fix, udm_geojson, udm_scene
from twin.recording.schemas import (
    CONFIG_CHANNEL,
    EGO_POSE_CHANNEL,
    EGO_STATE_CHANNEL,
    GNSS_CHANNEL,
    METRICS_CHANNEL,
    TF_CHANNEL,
    UDM_LATENCY_CHANNEL,
    UDM_MAP_CHANNEL,
    UDM_RESPONSE_CHANNEL,
    UDM_SCENE_CHANNEL,
)
from twin.recording.writer import DEFAULT_FLUSH_INTERVAL_S, RECORDING_NAME, Recorder, time_ns
from twin.session.hooks import Frame, SessionHook, SessionView
from twin.udm.model import UdmObject

log = logging.getLogger(__name__)

POSE_RATE_HZ = 10.0  # Foxglove pose and transform messages per simulated second


def json_safe(value: Any) -> Any:
    """Options as JSON: paths and other objects as text, tuples as lists, mappings as dicts."""
    if isinstance(value, (str, int, float, bool)) or value is None:
        return value
    if isinstance(value, Mapping):
        return {str(key): json_safe(item) for key, item in value.items()}
    if isinstance(value, (list, tuple, set, frozenset)):
        return [json_safe(item) for item in value]
    if isinstance(value, Path):
        return str(value)
    return str(value)


class SessionRecording:
    """One drive's MCAP file and what the hooks write into it; times are simulation seconds.

    The exact ego state goes in every step; the Foxglove pose and transform, which are for looking at, every
    ``pose_every`` steps (the drive's 10 Hz by default), which halves what recording costs the loop.
    """

    def __init__(self, path: Path, georeference: Any = None, flush_interval_s: float = DEFAULT_FLUSH_INTERVAL_S,
                 pose_every: int = 1):
        self.recorder = Recorder(path, flush_interval_s=flush_interval_s)
        self.path = path
        self.georeference = georeference
        self.pose_every = max(1, pose_every)
        self.ground_z = 0.0

    def log_time(self, t: float) -> int:
        return self.recorder.epoch_ns + time_ns(t)

    def config(self, config: Mapping[str, Any], **extra: Any) -> None:
        self.recorder.write(CONFIG_CHANNEL, 0.0, {"config": json_safe(config), **json_safe(extra)})

    def frame(self, frame: Frame) -> None:
        log_time = self.log_time(frame.t)
        self.ground_z = frame.z
        self.recorder.write(EGO_STATE_CHANNEL, frame.t, ego_state(frame))
        if frame.step % self.pose_every == 0:
            self.recorder.write(EGO_POSE_CHANNEL, frame.t, ego_pose(frame, log_time))
            self.recorder.write(TF_CHANNEL, frame.t, ego_transform(frame, log_time))
        if frame.gnss is not None:
            self.recorder.write(GNSS_CHANNEL, frame.gnss.t, location_fix(frame.gnss, self.log_time(frame.gnss.t)))

    def udm_response(self, t: float, step: int, answer: dict[str, Any], objects: Sequence[UdmObject]) -> None:
        """One UDM answer as it reached the simulation at ``step`` (``answer``: status, latencies, ...)."""
        self.recorder.write(UDM_RESPONSE_CHANNEL, t, {"step": step, **answer,
                                                      "features": [obj.to_record() for obj in objects]})
        latency = {key: answer.get(key) for key in ("frame", "status", "attempts", "client_latency_s",
                                                    "loop_latency_s", "error")}
        self.recorder.write(UDM_LATENCY_CHANNEL, t, {"step": step, **latency})
        if answer.get("status") == "ok":
            log_time = self.log_time(t)
            self.recorder.write(UDM_SCENE_CHANNEL, t, udm_scene(objects, self.georeference, self.ground_z,
                                                                log_time))
            self.recorder.write(UDM_MAP_CHANNEL, t, udm_geojson(objects))

    def metrics(self, t: float, metrics: Mapping[str, Any]) -> None:
        self.recorder.write(METRICS_CHANNEL, t, json_safe(metrics))

    def close(self) -> None:
        self.recorder.close()


class RecordingHook(SessionHook):
    """Created by ``twin.session.plugins`` from the drive options (``record``: None/True on, False off)."""

    name = "record"

    def __init__(self, options: Mapping[str, Any] | None = None, *,
                 flush_interval_s: float = DEFAULT_FLUSH_INTERVAL_S, pose_rate_hz: float = POSE_RATE_HZ) -> None:
        self.options = dict(options or {})
        self.flush_interval_s = flush_interval_s
        self.pose_rate_hz = pose_rate_hz
        self.recording: SessionRecording | None = None
        self._last_t = 0.0

    def start(self, session: SessionView) -> None:
        path = Path(session.out_dir) / RECORDING_NAME
        pose_every = max(1, round(1.0 / (self.pose_rate_hz * session.dt)))
        self.recording = SessionRecording(path, getattr(session.odr, "georeference", None), self.flush_interval_s,
                                          pose_every)
        self.recording.config(
            session.config, build_dir=session.build_dir, dt=session.dt, twin=__version__,
            recorded_at=datetime.now(UTC).isoformat(timespec="seconds"),
        )
        bus.attach(session, self.recording)

    def after_step(self, session: SessionView, frame: Frame) -> None:
        if self.recording is not None:
            self._last_t = frame.t
            self.recording.frame(frame)

    def finish(self, session: SessionView, metrics: dict[str, Any]) -> None:
        if self.recording is None:
            return
        bus.detach(session)
        metrics["recording"] = RECORDING_NAME
        metrics["recording_messages"] = self.recording.recorder.messages + 1  # this metrics message too
        try:
            self.recording.metrics(self._last_t, metrics)
        finally:
            self.recording.close()
            self.recording = None
