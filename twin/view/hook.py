"""``twin drive --view [--view-port N] [--view-rate HZ] [--no-browser]``: the drive, live in the browser.

The hook binds the port when it is created (a taken port is one line before any set-up), starts the live view
server (tavf_mapkit/view/live.py) in a child process when the drive starts, and after a step hands it a small
snapshot -- the step's ego ``Frame`` fields, the traffic hook's SUMO actors as numpy arrays, the UDM hook's
objects when they changed -- at most ``rate_hz`` times per wall-clock second. Everything else in a step is one
clock read. The hand-over never waits: it is skipped (and counted) when the socket pair to the child has no
room, i.e. when the child is stuck, so the drive never depends on the browser or the server; it changes
nothing the drive computes either (trajectory.csv is byte-identical with and without --view).

The hook is not a drive option recorded with the session (``twin replay --resimulate`` must not open a view):
``twin drive`` appends it to the hooks itself, last, so it sees what the traffic and UDM hooks did that step.
"""

from __future__ import annotations

import logging
import sys
import time
from pathlib import Path
from typing import Any

from tavf_mapkit.errors import InputError, MapkitError
from twin.session.hooks import Frame, SessionHook, SessionView

log = logging.getLogger(__name__)

DEFAULT_PORT = 8790  # beside mapkit view's 8780, so both can run at once
DEFAULT_RATE_HZ = 10.0
# the child lingers up to 1 s for a watching page and stops its server within 2 s; a frozen one is killed after
# twice this (no answer to "close", then no exit)
CLOSE_TIMEOUT_S = 3.0


class LiveViewHook(SessionHook):
    name = "view"

    def __init__(self, build_dir: str | Path, *, port: int = DEFAULT_PORT, rate_hz: float = DEFAULT_RATE_HZ,
                 browser: bool = True, basemap: bool = False, announce: bool = True) -> None:
        from tavf_mapkit.view.server import HOST, bind

        if not rate_hz > 0:
            raise InputError(f"--view-rate must be above 0 Hz, not {rate_hz:g}")
        self.build_dir = Path(build_dir)
        self.period_s = 1.0 / float(rate_hz)
        self.rate_hz = float(rate_hz)
        self.browser = browser
        self.basemap = basemap
        self.announce = announce
        try:
            self.sock = bind(port)
        except OSError as error:
            raise InputError(f"cannot listen on {HOST}:{port}: {error.strerror or error} "
                             f"(give another --view-port; 0 picks a free one)") from None
        self.url = f"http://{HOST}:{self.sock.getsockname()[1]}/"
        self.child = None
        self.sent = 0
        self.skipped = 0  # snapshots not handed over: no room in the socket pair (the child is behind or stuck)
        self._next_send = 0.0
        self.hand_over_seconds = 0.0  # what the hand-overs took the loop (the rest of a step is one clock read)
        self._last_frame: Frame | None = None
        self._traffic = self._udm = None
        self._udm_objects = None  # the UDM hook's objects tuple last handed over (identity: changed or not)

    def start(self, session: SessionView) -> None:
        from tavf_mapkit.opendrive.georef import GeoReference
        from tavf_mapkit.view.server import has_display
        from twin.childproc import ChildProcess
        from twin.sim.build import georeference_for_driving

        hooks = getattr(session, "hooks", ())
        self._traffic = next((hook for hook in hooks if getattr(hook, "name", None) == "traffic"), None)
        self._udm = next((hook for hook in hooks if getattr(hook, "name", None) == "udm"), None)
        georef, _ = georeference_for_driving(session.odr)
        open_browser = self.browser and has_display()
        settings = {"socket_fd": self.sock.fileno(), "build": str(session.build_dir), "rate_hz": self.rate_hz,
                    "basemap": self.basemap, "open_browser": open_browser,
                    # a fresh one: the session's has its pyproj transformers cached, which need not pickle
                    "georef": GeoReference(georef.text, georef.offset)}
        try:
            self.child = ChildProcess("tavf_mapkit.view.live", "the live view", settings,
                                      pass_fds=(self.sock.fileno(),))
        except RuntimeError as error:
            raise MapkitError(str(error)) from None
        finally:
            self.sock.close()  # the child holds the port now; it is free again when the child ends
        if self.announce:
            how = "" if open_browser else ("  (open it in a browser)" if self.browser else "")
            print(f"twin drive: live view on {self.url} while the drive runs{how}", file=sys.stderr, flush=True)

    def after_step(self, session: SessionView, frame: Frame) -> None:
        self._last_frame = frame
        now = time.monotonic()
        if now >= self._next_send:
            self._next_send = now + self.period_s
            self._hand_over(frame)
            self.hand_over_seconds += time.monotonic() - now

    def finish(self, session: SessionView, metrics: dict[str, Any]) -> None:
        if self.child is None:
            self.sock.close()
            return
        try:
            if self._last_frame is not None:
                self._hand_over(self._last_frame)  # the page ends on the drive's last step
            self.child.close(CLOSE_TIMEOUT_S)
        finally:
            metrics["view"] = {"url": self.url, "rate_hz": self.rate_hz, "states_sent": self.sent,
                               "states_skipped": self.skipped, "hand_over_seconds": round(self.hand_over_seconds, 6)}
            self.child = None

    def _hand_over(self, frame: Frame) -> None:
        child = self.child
        if child is None or child.closed:
            return
        # a snapshot of a hundred actors is ~5 kB: no room only when the child has not read for many snapshots
        if not child.has_room():
            self.skipped += 1
            return
        snapshot = {"t": frame.t, "step": frame.step,
                    "ego": [frame.x, frame.y, frame.z, frame.yaw, frame.speed, frame.lat, frame.lon, frame.road_id,
                            frame.lane_id],
                    "traffic": self._traffic_arrays()}
        udm = self._udm
        if udm is not None and udm.objects is not self._udm_objects:
            snapshot["udm"] = {"objects": [obj.to_record() for obj in udm.objects], "xy": udm.objects_xy}
            self._udm_objects = udm.objects
        try:
            child.send("state", snapshot)
            self.sent += 1
        except (OSError, ValueError) as error:
            log.warning("live view gone (%s); the drive goes on without it", error)
            child.closed = True

    def _traffic_arrays(self) -> dict | None:
        snapshot = getattr(self._traffic, "snapshot", None)
        if snapshot is None:
            return None
        actors = snapshot.actors
        return {"ids": actors.ids, "person": actors.is_person, "centre": actors.centre, "yaw": actors.yaw,
                "length": actors.length, "width": actors.width}
