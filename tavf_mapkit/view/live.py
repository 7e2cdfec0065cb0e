"""The live view of ``twin drive --view``: the page of ``mapkit view`` following a drive while it runs.

This module is the server's side, run as a child process of the twin (``python -m tavf_mapkit.view.live FD``,
started by ``twin/view/hook.py`` through ``twin.childproc``). Why a process and not a thread beside the
simulation loop: the same reason as the twin's UDM client and traffic publisher (docs/traffic.md,
"Benchmark") -- Python work on another thread takes the GIL from the loop at every socket read. The hook hands
this process a small snapshot (the ego, the SUMO actors as numpy arrays, the UDM objects when they changed) at
most ``rate_hz`` times per wall-clock second, only when the socket pair has room, so the loop never waits; here
the newest snapshot becomes the JSON of ``/api/live`` once, and the page polls that at the same rate.

The map and scene data of the page are computed on the first request for them: a drive nobody watches pays
nothing for them, and one that is watched pays on this process's core, not the loop's. When the drive ends the
state is marked finished; a page that polled within the last second gets up to ``LINGER_S`` to see it (and stop
polling) before the server stops.
"""

from __future__ import annotations

import json
import math
import os
import socket
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from tavf_mapkit.view.server import HOST, create_app, make_server, open_in_browser

START_TIMEOUT_S = 20.0
LINGER_S = 1.0  # at most this long after the drive ended, for a watching page to get the final state
STOP_TIMEOUT_S = 5.0
NICE = 10
MAX_POLL_S = 0.1  # the newest snapshot is read at the view's rate, at least 10 times a second
DEGREE_DIGITS = 7  # traffic lat/lon as the replay writes them (runs.py): 1.1 cm


class LiveState:
    """The latest state of the drive as the JSON body of ``/api/live`` (built once per snapshot, under a lock:
    the reader thread writes it, the server's event loop reads it)."""

    def __init__(self, georef, rate_hz: float) -> None:
        self.georef = georef
        self.rate_hz = float(rate_hz)
        self.lock = threading.Lock()
        self.seq = 0
        self.finished = False
        self.udm: dict | None = None
        self.last_request = -math.inf  # time.monotonic() of the last /api/live request
        self.final_seen = threading.Event()  # a request got the finished state
        self._state: dict[str, Any] = {"t": None, "step": None, "ego": None, "traffic": None, "udm": None}
        self._body = self._encode()

    def page_options(self) -> dict:
        return {"rate_hz": self.rate_hz}

    def body(self) -> bytes:
        with self.lock:
            self.last_request = time.monotonic()
            if self.finished:
                self.final_seen.set()
            return self._body

    def watched(self, within_s: float = 1.0) -> bool:
        return time.monotonic() - self.last_request < within_s

    def update(self, snapshot: dict) -> None:
        """A snapshot of twin/view/hook.py: {t, step, ego: [x, y, z, yaw, speed, lat, lon, road, lane],
        traffic: None | {ids, person, centre, yaw, length, width}, udm: absent (unchanged) | {objects, xy}}."""
        t = snapshot["t"]
        x, y, z, yaw, speed, lat, lon, road, lane = snapshot["ego"]
        state = {"t": t, "step": snapshot["step"],
                 "ego": {"t": t, "x": x, "y": y, "z": z, "yaw": yaw, "speed": speed, "lat": lat, "lon": lon,
                         "road": road, "lane": lane},
                 "traffic": self._traffic(t, snapshot.get("traffic"))}
        if "udm" in snapshot:
            self.udm = self._udm(t, snapshot["step"], snapshot["udm"])
        state["udm"] = self.udm
        with self.lock:
            self.seq += 1
            self._state = state
            self._body = self._encode()

    def finish(self) -> None:
        with self.lock:
            self.seq += 1
            self.finished = True
            self._body = self._encode()

    def _encode(self) -> bytes:
        return json.dumps({"seq": self.seq, "finished": self.finished, "rate_hz": self.rate_hz, **self._state},
                          separators=(",", ":"), allow_nan=False).encode("utf-8")

    def _traffic(self, t: float, traffic: dict | None) -> dict | None:
        """The frame format of a replay (runs.py): box centres, yaw, size, and WGS84 -- one vectorised pass."""
        if traffic is None:
            return None
        centre = np.asarray(traffic["centre"], dtype=float).reshape(-1, 3)
        lon, lat = self.georef.local_to_wgs84(centre[:, 0], centre[:, 1])
        return {"t": t, "ids": list(traffic["ids"]), "person": np.asarray(traffic["person"], dtype=bool).tolist(),
                "x": np.round(centre[:, 0], 3).tolist(), "y": np.round(centre[:, 1], 3).tolist(),
                "z": np.round(centre[:, 2], 3).tolist(), "yaw": np.round(traffic["yaw"], 4).tolist(),
                "length": np.asarray(traffic["length"], dtype=float).tolist(),
                "width": np.asarray(traffic["width"], dtype=float).tolist(),
                "lon": np.round(np.atleast_1d(lon), DEGREE_DIGITS).tolist(),
                "lat": np.round(np.atleast_1d(lat), DEGREE_DIGITS).tolist()}

    @staticmethod
    def _udm(t: float, step: int, udm: dict) -> dict:
        """The objects of the UDM's latest answer, as a replay's answer (runs.py) with the local x, y."""
        objects = []
        for record, (x, y) in zip(udm["objects"], np.asarray(udm["xy"], dtype=float).reshape(-1, 2)):
            objects.append({key: record.get(key) for key in ("id", "layer", "type", "lat", "lon", "heading", "extent")}
                           | {"x": round(float(x), 3), "y": round(float(y), 3)})
        return {"t": t, "step": step, "status": "ok", "objects": objects}


class LazyViewData:
    """server.ViewData of a build whose map and scene are computed on the first request for either."""

    def __init__(self, build_path: str | Path, basemap: bool = False) -> None:
        from twin.sim.build import Build

        self.runs: list[bytes] = []  # a live page replays no run folder
        self.run_names: list[str] = []
        self.build_path = Build.open(build_path).path
        self.basemap = basemap
        self._lock = threading.Lock()
        self._data = None

    def _loaded(self):
        with self._lock:  # two requests at once compute it once
            if self._data is None:
                from tavf_mapkit.view.server import load_view_data

                self._data = load_view_data(self.build_path, basemap=self.basemap)
            return self._data

    @property
    def map_json(self) -> bytes:
        return self._loaded().map_json

    @property
    def scene_json(self) -> bytes:
        return self._loaded().scene_json


def _serve(settings: dict[str, Any], parent) -> None:
    """The child: serve the page on the socket the twin bound, take snapshots until the drive ends."""
    try:
        os.nice(NICE)  # a viewer: the simulation comes first when the cores are busy
    except OSError:
        pass
    sock = socket.socket(fileno=int(settings["socket_fd"]))
    poll_s = min(1.0 / float(settings["rate_hz"]), MAX_POLL_S)
    state = LiveState(settings["georef"], settings["rate_hz"])
    app = create_app(LazyViewData(settings["build"], basemap=bool(settings.get("basemap"))), live=state)
    listening = threading.Event()
    server = make_server(app, on_ready=listening.set)
    failed: list[BaseException] = []

    def run() -> None:
        try:
            server.run(sockets=[sock])
        except BaseException as error:  # noqa: BLE001 -- reported to the parent as why the view did not start
            failed.append(error)
            listening.set()

    thread = threading.Thread(target=run, name="live-view-server", daemon=True)
    thread.start()
    if not listening.wait(START_TIMEOUT_S) or failed:
        raise RuntimeError(f"the server did not listen: {failed[0] if failed else 'timeout'}")
    parent.stats = lambda: {"states": state.seq}
    parent.ready()
    if settings.get("open_browser"):
        open_in_browser(f"http://{HOST}:{sock.getsockname()[1]}/")
    try:
        closing = False
        while not closing:
            # read on a timer, never blocked in recv: a reader blocked on the socket is woken by every snapshot
            # and, on a busy machine, scheduled onto the simulation's core at once (the twin's send then took
            # 1.3 ms instead of 20 us); asleep here, the snapshots just wait in the socket for the next read
            time.sleep(poll_s)
            newest = None
            for message in parent.waiting(block=False):
                if message[0] == "state":
                    if newest is not None and "udm" in newest and "udm" not in message[1]:
                        message[1]["udm"] = newest["udm"]  # a skipped snapshot's new UDM objects still count
                    newest = message[1]
                elif message[0] == "close":
                    closing = True
            if newest is not None:
                state.update(newest)
            closing = closing or parent.gone
        state.finish()
        if state.watched() and not parent.gone:
            state.final_seen.wait(LINGER_S)
    finally:
        server.should_exit = True
        thread.join(STOP_TIMEOUT_S)


if __name__ == "__main__":
    from twin.childproc import serve

    serve(_serve, "the live view")
