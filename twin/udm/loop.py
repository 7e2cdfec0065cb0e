"""The UDM in the simulation loop: ``twin drive --udm URL [--udm-every N] [--udm-bbox M]``.

Every ``every`` steps the hook asks the UDM for the ``side_m`` square around the latest GNSS fix (the vehicle's
own position before the first fix) and, at the end of every step, takes the answers that have arrived. The
simulation thread never waits on the network: queries go to a ``UdmProcessClient`` (a ``UdmClient`` in a
child process, so the busy simulation thread cannot delay its socket reads) and ``poll`` only reads a pipe.

What the simulation gets: ``objects`` -- the objects of the latest successful answer, in WGS84 and in the map's
local frame -- and a cautious target speed near hazards the UDM reports on the path ahead (``CAUTION_TYPES``).
Because answers change the drive, each answer is recorded with the step at which it became available, and
``twin replay --resimulate`` delivers the recorded answers at the same steps (``udm_replay`` option) instead
of asking a server.

Faults (unreachable, slow, 5xx, malformed answers) become counted responses; the drive goes on. At the end,
``metrics.json`` gets a ``udm`` section (requests, errors by kind, latency percentiles).
"""

from __future__ import annotations

import logging
import time
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from twin.recording import bus
from twin.session.hooks import Frame, SessionHook, SessionView
from twin.udm.client import OK, LatencyLog, UdmClient, UdmResponse
from twin.udm.model import UdmObject

log = logging.getLogger(__name__)

DEFAULT_EVERY = 10
DEFAULT_SIDE_M = 200.0
DEFAULT_TIMEOUT_S = 1.0
DEFAULT_RETRIES = 2
FINISH_WAIT_S = 2.0  # how long the end of a drive waits for answers still on their way

# Objects on the path ahead that make the car slow down, and how: within CAUTION_RANGE_M along the path
# and CAUTION_OFFSET_M of it, the target speed is capped at CAUTION_SPEED_MS (30 km/h).
CAUTION_TYPES = frozenset({"roadworks", "hazard", "accident", "obstacle", "pedestrian"})
CAUTION_RANGE_M = 40.0
CAUTION_OFFSET_M = 4.0
CAUTION_SPEED_MS = 30.0 / 3.6


@dataclass(frozen=True)
class Answer:
    """A UDM response as the simulation received it: at the end of ``step``, monotonic time ``t_available``."""

    step: int
    t_available: float
    response: UdmResponse
    centre: tuple[float, float] | None = None  # the (lat, lon) the query asked about


class RecordedAnswers:
    """Answers of a recording, handed out at the steps they were delivered (``twin replay --resimulate``)."""

    def __init__(self, records: Sequence[Mapping[str, Any]]) -> None:
        self._by_step: dict[int, list[UdmResponse]] = {}
        for record in records:
            self._by_step.setdefault(int(record["step"]), []).append(response_from_record(record))
        self.submitted = 0

    @classmethod
    def from_recording(cls, path: str | Path) -> RecordedAnswers:
        from twin.recording.reader import read_recording
        from twin.recording.schemas import UDM_RESPONSE_CHANNEL

        return cls(read_recording(path, topics={UDM_RESPONSE_CHANNEL.topic}).udm_responses)

    def take(self, step: int) -> list[UdmResponse]:
        return self._by_step.pop(step, [])


def response_to_record(response: UdmResponse) -> dict[str, Any]:
    """The fields of a response a recording keeps (objects go separately, exactly, as ``features``)."""
    return {"frame": response.frame, "t_publish": response.t_publish, "t_sent": response.t_sent,
            "t_received": response.t_received, "status": response.status, "attempts": response.attempts,
            "http_status": response.http_status, "error": response.error,
            "client_latency_s": response.client_latency_s, "loop_latency_s": response.loop_latency_s}


def response_from_record(record: Mapping[str, Any]) -> UdmResponse:
    return UdmResponse(
        frame=int(record["frame"]), t_publish=record["t_publish"], t_sent=record.get("t_sent"),
        t_received=record["t_received"], status=record["status"],
        objects=tuple(UdmObject.from_record(feature) for feature in record.get("features", ())),
        attempts=record.get("attempts", 0), http_status=record.get("http_status"), error=record.get("error", ""),
    )


class UdmHook(SessionHook):
    """Created by ``twin.session.plugins`` with the drive options: ``udm`` (base URL), ``udm_every``,
    ``udm_bbox`` (side in metres), optional ``udm_timeout``, ``udm_retries``, ``udm_client``
    (``process``, the default, or ``thread``), ``udm_realtime`` (the client process under SCHED_FIFO,
    twin.udm.priority) and ``udm_replay`` (a recording whose answers to replay)."""

    name = "udm"

    def __init__(self, options: Mapping[str, Any] | None = None, **overrides: Any) -> None:
        options = {**(options or {}), **overrides}
        self.url = str(options.get("udm") or "")
        self.every = max(1, int(options.get("udm_every") or DEFAULT_EVERY))
        self.side_m = float(options.get("udm_bbox") or DEFAULT_SIDE_M)
        self.timeout_s = float(options.get("udm_timeout") or DEFAULT_TIMEOUT_S)
        retries = options.get("udm_retries")
        self.retries = DEFAULT_RETRIES if retries is None else int(retries)
        self.client_kind = str(options.get("udm_client") or "process")
        self.realtime = bool(options.get("udm_realtime"))
        self.client_policy: str | None = None  # the client process's, as the OS reports it once it is ready
        self.replay_path = options.get("udm_replay")
        self.client: Any = None
        self.replay: RecordedAnswers | None = None
        self.latency_log: LatencyLog | None = None
        self.answers: list[Answer] = []  # every answer the simulation received, in order
        self.objects: tuple[UdmObject, ...] = ()  # of the latest successful answer
        self.objects_xy = np.empty((0, 2))  # the same objects in the map's local frame
        self.queries = 0
        self.errors: Counter[str] = Counter()
        self.steps = 0
        self.late_answers = 0  # arrived after the last step: logged and counted, never used
        self.loop_seconds = 0.0  # spent in this hook on the simulation thread
        self._centres: dict[int, tuple[float, float]] = {}  # step of a query -> the (lat, lon) it asked about
        self._latest_fix: tuple[float, float] | None = None
        self._georeference: Any = None
        self._caution_xy = np.empty((0, 2))

    # --- hook interface ------------------------------------------------------------------------------------

    def start(self, session: SessionView) -> None:
        self._georeference = getattr(session.odr, "georeference", None)
        self.latency_log = LatencyLog(Path(session.out_dir))
        if self.replay_path:
            self.replay = RecordedAnswers.from_recording(self.replay_path)
            return
        options = {"timeout_s": self.timeout_s, "max_retries": self.retries}
        if self.client_kind == "thread":
            if self.realtime:  # the thread shares the simulation's process: raising it would raise the simulation
                log.warning("udm_realtime applies to the UDM client process only; the thread client runs at the "
                            "simulation's priority")
            self.client = UdmClient(self.url, **options)
        else:
            from twin.udm.process_client import UdmProcessClient

            self.client = UdmProcessClient(self.url, realtime=self.realtime, **options)
            self.client_policy = self.client.scheduling_policy()

    def after_step(self, session: SessionView, frame: Frame) -> None:
        started = time.perf_counter()
        responses = self.client.poll() if self.client is not None else self._replayed(frame.step)
        if responses:
            self._receive(session, frame, responses)
        if frame.gnss is not None:
            self._latest_fix = (frame.gnss.lat, frame.gnss.lon)
        if frame.step % self.every == 0:
            lat, lon = self._latest_fix or (frame.lat, frame.lon)
            self.queries += 1
            self._centres[frame.step] = (lat, lon)
            if self.client is not None:
                self.client.submit(lat, lon, self.side_m, frame=frame.step, t_publish=time.monotonic())
        self.steps += 1
        self.loop_seconds += time.perf_counter() - started

    def target_speed(self, session: SessionView, t: float, speed: float) -> float:
        if not len(self._caution_xy) or speed <= CAUTION_SPEED_MS:
            return speed
        path = np.asarray(session.path_ahead(CAUTION_RANGE_M), dtype=float)
        if path.ndim != 2 or not len(path):
            return speed
        gaps = np.linalg.norm(self._caution_xy[:, None, :] - path[None, :, :2], axis=2)
        return min(speed, CAUTION_SPEED_MS) if float(gaps.min()) <= CAUTION_OFFSET_M else speed

    def finish(self, session: SessionView, metrics: dict[str, Any]) -> None:
        if self.client is not None:
            # Answers still on their way are logged but never reached the simulation (no step).
            self.client.flush(FINISH_WAIT_S)
            late = self.client.poll()
            self.client.close(FINISH_WAIT_S)
            late += self.client.poll()
            for response in late:
                if response.status != OK:
                    self.errors[response.status] += 1
                if self.latency_log is not None:
                    self.latency_log.write(response)
            self.late_answers += len(late)
            stats = self.client.stats()
            client_stats = {"submitted": stats.submitted, "dropped": stats.dropped, "abandoned": stats.abandoned,
                            "requests": stats.requests, "retries": stats.retries, "ok": stats.ok,
                            "errors": dict(stats.errors), "realtime": self.realtime, "policy": self.client_policy}
        else:
            client_stats = {"replayed": True}
        if self.latency_log is not None:
            self.latency_log.close()
        cost_ms = 1000.0 * self.loop_seconds / self.steps if self.steps else 0.0
        metrics["udm"] = {"url": self.url, "every": self.every, "bbox_m": self.side_m, "queries": self.queries,
                          "answers": len(self.answers), "late_answers": self.late_answers,
                          "errors": dict(self.errors),
                          "error_count": sum(self.errors.values()), **latency_summary(self.answers),
                          "loop_cost_ms_per_step": round(cost_ms, 4), "client": client_stats}

    # --- internals -----------------------------------------------------------------------------------------

    def _replayed(self, step: int) -> list[UdmResponse]:
        return self.replay.take(step) if self.replay is not None else []

    def _receive(self, session: SessionView, frame: Frame, responses: list[UdmResponse]) -> None:
        t_available = time.monotonic()
        recording = bus.recording_for(session)
        for response in responses:
            centre = self._centres.pop(response.frame, None)
            self.answers.append(Answer(frame.step, t_available, response, centre))
            if self.latency_log is not None:
                self.latency_log.write(response, step=frame.step, t_available=t_available)
            if response.status == OK:
                self._use(response.objects)
            else:
                self.errors[response.status] += 1
                log.warning("UDM query of step %d: %s %s", response.frame, response.status, response.error)
            if recording is not None:
                record = response_to_record(response)
                if centre is not None:
                    record["query"] = {"lat": centre[0], "lon": centre[1], "side_m": self.side_m}
                recording.udm_response(frame.t, frame.step, record, response.objects)
        if self.latency_log is not None:
            self.latency_log.flush()
        draw_objects(session, self.objects, self.objects_xy)

    def _use(self, objects: tuple[UdmObject, ...]) -> None:
        self.objects = objects
        if objects and self._georeference is not None:
            x, y = self._georeference.wgs84_to_local(np.array([o.lon for o in objects]),
                                                     np.array([o.lat for o in objects]))
            self.objects_xy = np.column_stack([x, y])
        else:
            self.objects_xy = np.empty((0, 2))
        caution = np.array([o.type in CAUTION_TYPES for o in objects], dtype=bool)
        self._caution_xy = self.objects_xy[caution] if len(self.objects_xy) else np.empty((0, 2))


def latency_summary(answers: Sequence[Answer]) -> dict[str, Any]:
    """Percentiles in ms of the successful answers: request (sent -> parsed), loop (fix published -> answer
    parsed) and available (fix published -> the simulation has it)."""
    ok = [answer for answer in answers if answer.response.status == OK]
    if not ok:
        return {"latency_ms": None}
    series = {
        "request": [a.response.client_latency_s for a in ok if a.response.client_latency_s is not None],
        "loop": [a.response.loop_latency_s for a in ok],
        "available": [a.t_available - a.response.t_publish for a in ok],
    }
    return {"latency_ms": {name: percentiles_ms(values) for name, values in series.items()}}


def percentiles_ms(values: Sequence[float]) -> dict[str, float] | None:
    if not len(values):
        return None
    array = np.asarray(values, dtype=float) * 1000.0
    return {"min": round(float(array.min()), 3), "mean": round(float(array.mean()), 3),
            "p50": round(float(np.percentile(array, 50)), 3), "p95": round(float(np.percentile(array, 95)), 3),
            "max": round(float(array.max()), 3), "n": len(array)}


_drawn: dict[int, list[int]] = {}  # pybullet client -> debug item ids of the UDM objects drawn last


def draw_objects(session: SessionView, objects: Sequence[UdmObject], xy: np.ndarray) -> None:
    """Draw the objects as labelled posts in the pybullet GUI (nothing without a GUI)."""
    client = getattr(session, "client_id", None)
    if client is None:
        return
    import pybullet

    try:
        if pybullet.getConnectionInfo(client).get("connectionMethod") != pybullet.GUI:
            return
    except pybullet.error:
        return
    for item in _drawn.pop(client, []):
        pybullet.removeUserDebugItem(item, physicsClientId=client)
    ground = session.ego.z
    items = []
    for obj, (x, y) in zip(objects, xy, strict=False):
        top = [float(x), float(y), ground + 3.0]
        items.append(pybullet.addUserDebugLine([float(x), float(y), ground], top, [0.2, 0.4, 1.0], 3.0,
                                               physicsClientId=client))
        items.append(pybullet.addUserDebugText(f"{obj.type} {obj.object_class}".strip(), top, [1, 1, 1], 1.0,
                                               physicsClientId=client))
    _drawn[client] = items
