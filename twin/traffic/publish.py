"""SUMO traffic as live UDM data: signal phases (layer 3), vehicles and pedestrians (layer 4).

``traffic_features`` turns one snapshot into GeoJSON Features of the UDM model (docs/udm-api.md); the
``UdmPublisher`` POSTs them in batches from a worker thread, so the simulation never waits on the network.
Batches merge by object id while a POST is in flight (the newest state of each object wins), so a slow UDM
lowers the publish rate instead of building a queue. Objects that left SUMO are posted once more with a
``valid_until`` in the past: the UDM stops returning them at once and purges them later.

Validity: highly dynamic objects get ``validity_periods`` publish periods (default 3), measured on the wall
clock the UDM expires them by -- the larger of the simulated period and the measured wall time between
publishes, so they neither flicker when the twin runs faster than real time nor linger when it runs slower.
"""

from __future__ import annotations

import math
import re
import threading
import time
import zlib
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import httpx
import numpy as np

from twin.traffic.frames import NetFrame
from twin.traffic.sumo import SignalLinks, TrafficSnapshot

SIGNAL_STATE_NAMES = {"r": "red", "y": "yellow", "G": "green", "g": "green_minor", "s": "green_stop",
                      "u": "red_yellow", "o": "off_blinking", "O": "off"}
_BAD_ID_CHARS = re.compile(r"[^A-Za-z0-9._:@~-]")
_SIGNAL_VALIDITY_S = 10.0  # signal phases are re-sent on every change and at least every few seconds
_SIGNAL_REFRESH_S = 2.0


def udm_id(prefix: str, name: str) -> str:
    """A UDM object id for a SUMO id: SUMO ids may hold any character, UDM ids only A-Z a-z 0-9 . _ : @ ~ -."""
    clean = _BAD_ID_CHARS.sub("_", name)
    if clean != name:
        clean = f"{clean}~{zlib.crc32(name.encode()):08x}"  # keep ids of different SUMO ids apart
    return f"{prefix}{clean}"[:128]


def _feature(object_id: str, layer: int, kind: str, lon: float, lat: float, **properties: Any) -> dict:
    return {"type": "Feature", "id": object_id, "geometry": {"type": "Point", "coordinates": [lon, lat]},
            "properties": {"layer": layer, "type": kind, **properties}}


def actor_features(snapshot: TrafficSnapshot, frame: NetFrame, valid_until: float, source: str = "sumo"
                   ) -> list[dict]:
    """Layer-4 objects of the snapshot's vehicles and persons, at the centre of their boxes."""
    actors = snapshot.actors
    if not len(actors):
        return []
    centre = actors.centre
    lon, lat = frame.local_to_wgs84(centre[:, 0], centre[:, 1])
    heading = frame.compass_heading(actors.yaw, centre[:, 0], centre[:, 1])
    features = []
    for i, actor in enumerate(actors.ids):
        person = bool(actors.is_person[i])
        features.append(_feature(
            udm_id("sumo-person-" if person else "sumo-vehicle-", actor), 4, "pedestrian" if person else "vehicle",
            float(lon[i]), float(lat[i]), **{"class": actors.type_id[i][:64]}, name=actor[:256],
            heading=round(float(heading[i]), 3),
            extent={"length": float(actors.length[i]), "width": float(actors.width[i]),
                    "height": float(actors.height[i])},
            valid_until=valid_until, source=source))
    return features


def signal_features(links: SignalLinks, state: np.ndarray, rows: np.ndarray, frame: NetFrame,
                    valid_until: float, source: str = "sumo") -> list[dict]:
    """Layer-3 signal-phase objects for the given link rows, at their stop lines."""
    if not len(rows):
        return []
    lon, lat = frame.local_to_wgs84(links.stop_x[rows], links.stop_y[rows])
    heading = frame.compass_heading(links.stop_yaw[rows], links.stop_x[rows], links.stop_y[rows])
    features = []
    for k, row in enumerate(rows):
        tls, link = links.tls_id[row], int(links.link_index[row])
        letter = str(state[row])
        features.append(_feature(
            udm_id("sumo-signal-", f"{tls}:{link}:{links.in_lane[row]}:{links.out_lane[row]}"), 3, "signal_phase",
            float(lon[k]), float(lat[k]), **{"class": SIGNAL_STATE_NAMES.get(letter, "unknown")},
            name=f"{tls} link {link}: {links.in_lane[row]} -> {links.out_lane[row]}"[:256],
            heading=round(float(heading[k]), 3), valid_until=valid_until, source=source))
    return features


def perceived_features(snapshot: TrafficSnapshot, frame: NetFrame, ego_xy: tuple[float, float], range_m: float,
                       noise_m: float, rng: np.random.Generator, valid_until: float,
                       source: str = "ego-perception") -> list[dict]:
    """What the ego 'sees' (ground truth within ``range_m``, Gaussian position noise) as a data provider."""
    actors = snapshot.actors
    if not len(actors):
        return []
    centre = actors.centre
    near = np.flatnonzero(np.hypot(centre[:, 0] - ego_xy[0], centre[:, 1] - ego_xy[1]) <= range_m)
    if not len(near):
        return []
    noise = rng.normal(0.0, noise_m, size=(len(near), 2)) if noise_m > 0 else np.zeros((len(near), 2))
    x, y = centre[near, 0] + noise[:, 0], centre[near, 1] + noise[:, 1]
    lon, lat = frame.local_to_wgs84(x, y)
    heading = frame.compass_heading(actors.yaw[near], x, y)
    return [_feature(udm_id("cp-", actors.ids[i]), 4, "pedestrian" if actors.is_person[i] else "vehicle",
                     float(lon[k]), float(lat[k]), heading=round(float(heading[k]), 3),
                     **{"class": "perceived"}, valid_until=valid_until, source=source)
            for k, i in enumerate(near)]


@dataclass
class PublisherStats:
    batches: int = 0  # publish() calls
    posts: int = 0  # HTTP POSTs sent (merged batches)
    objects: int = 0  # objects in successful POSTs
    errors: Counter = field(default_factory=Counter)
    post_seconds: list[float] = field(default_factory=list)
    last_error: str = ""


class UdmPublisher:
    """POSTs feature batches to ``base_url``/objects with a bearer token, off the simulation thread."""

    MAX_FEATURES_PER_POST = 10000  # the server's limit

    def __init__(self, base_url: str, token: str, *, timeout_s: float = 1.0) -> None:
        self.base_url = base_url
        self.stats = PublisherStats()
        self._headers = {"Authorization": f"Bearer {token}", "Content-Type": "application/geo+json"}
        self._timeout_s = timeout_s
        self._pending: dict[str, dict] = {}
        self._in_flight = False
        self._lock = threading.Condition()
        self._stopping = False
        self._thread = threading.Thread(target=self._run, name="udm-publisher", daemon=True)
        self._thread.start()

    def publish(self, features: list[dict]) -> None:
        """Queue features (never blocks); a newer feature replaces a queued one with the same id."""
        if not features:
            return
        with self._lock:
            for feature in features:
                self._pending[feature["id"]] = feature
            self.stats.batches += 1
            self._lock.notify_all()

    def flush(self, timeout_s: float = 5.0) -> bool:
        """Wait until everything queued was posted (tests, the end of a run); False on timeout."""
        with self._lock:
            self._lock.wait_for(lambda: not (self._pending or self._in_flight) or not self._thread.is_alive(),
                                timeout_s)
            return not (self._pending or self._in_flight)

    def close(self, timeout_s: float = 5.0) -> None:
        self.flush(timeout_s)
        with self._lock:
            self._stopping = True
            self._lock.notify_all()
        self._thread.join(timeout_s)

    def _run(self) -> None:
        with httpx.Client(base_url=self.base_url, timeout=self._timeout_s, headers=self._headers,
                          trust_env=False) as http:
            while True:
                with self._lock:
                    while not self._pending and not self._stopping:
                        self._lock.wait()
                    if self._stopping and not self._pending:
                        return
                    batch = list(self._pending.values())[: self.MAX_FEATURES_PER_POST]
                    for feature in batch:
                        del self._pending[feature["id"]]
                    self._in_flight = True
                try:
                    self._post(http, batch)
                finally:
                    with self._lock:
                        self._in_flight = False
                        self._lock.notify_all()

    def _post(self, http: httpx.Client, batch: list[dict]) -> None:
        started = time.monotonic()
        try:
            reply = http.post("objects", json={"type": "FeatureCollection", "features": batch})
        except httpx.HTTPError as error:
            self._error(type(error).__name__, str(error))
            return
        except Exception as error:  # noqa: BLE001 -- the worker must survive anything and keep counting
            self._error("internal", f"{type(error).__name__}: {error}")
            return
        if reply.status_code != 201:
            self._error(f"http_{reply.status_code}", reply.text[:200])
            return
        with self._lock:
            self.stats.posts += 1
            self.stats.objects += len(batch)
            self.stats.post_seconds.append(time.monotonic() - started)

    def _error(self, kind: str, message: str) -> None:
        with self._lock:
            self.stats.errors[kind] += 1
            self.stats.last_error = message[:200]


class TrafficPublishing:
    """Decides what to send when: actors every period, signals on change and every few seconds."""

    def __init__(self, publisher: UdmPublisher, frame: NetFrame, links: SignalLinks, *, period_sim_s: float,
                 validity_periods: float = 3.0, source: str = "sumo") -> None:
        self.publisher = publisher
        self.frame = frame
        self.links = links
        self.period_sim_s = period_sim_s
        self.validity_periods = validity_periods
        self.source = source
        self._last_wall: float | None = None
        self._wall_period = period_sim_s
        self._sent_state: np.ndarray | None = None
        self._signals_sent_wall = -math.inf
        self._published_actors: set[str] = set()

    def publish(self, snapshot: TrafficSnapshot, extra: list[dict] | None = None) -> int:
        """Queue one batch for this snapshot; returns the number of features queued."""
        now = time.time()
        if self._last_wall is not None:
            # smoothed, so one slow step does not shorten every object's life
            self._wall_period = 0.8 * self._wall_period + 0.2 * (now - self._last_wall)
        self._last_wall = now
        valid_until = now + self.validity_periods * max(self.period_sim_s, self._wall_period)
        features = actor_features(snapshot, self.frame, valid_until, self.source)
        ids = {feature["id"] for feature in features}
        gone = self._published_actors - ids
        features += [_feature(object_id, 4, "vehicle", 0.0, 0.0, valid_until=now - 1.0, source=self.source)
                     for object_id in sorted(gone)]  # expired at once; position irrelevant
        self._published_actors = ids
        state = snapshot.signal_state
        if len(state):
            if self._sent_state is None or now - self._signals_sent_wall >= _SIGNAL_REFRESH_S:
                rows = np.arange(len(state))
                self._signals_sent_wall = now
            else:
                rows = np.flatnonzero(state != self._sent_state)
            self._sent_state = state.copy()
            features += signal_features(self.links, state, rows, self.frame, now + _SIGNAL_VALIDITY_S, self.source)
        features += extra or []
        self.publisher.publish(features)
        return len(features)
