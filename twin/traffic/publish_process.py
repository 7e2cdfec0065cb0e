"""Traffic publishing to the UDM from a child process, so the simulation thread only writes to a pipe.

Why a process (the same reason as ``twin/udm/process_client.py``): turning 120 actors into GeoJSON,
encoding it and POSTing it is Python work that holds the GIL. On a worker thread beside the simulation loop
it took the GIL from the loop at every socket read, and the loop's own steps (libsumo, pybullet, numpy) got
2-3x slower (docs/traffic.md, "Benchmark"). Here the loop pickles the step's ``TrafficSnapshot`` (~0.1 ms)
into a socket pair; the child builds the features with the very same ``TrafficPublishing`` and posts them
with ``UdmPublisher``.

Rate: by default every snapshot is handed over (10 Hz of simulated time). ``min_interval_s`` sets a floor of
wall time between hand-overs: a twin at 10x real time otherwise posts 100 batches per wall second, and the
UDM server and this child together take a core of a two-core machine away from the simulation, for updates
no real-time consumer can use. A snapshot that comes
too early is held and replaced by the next one (newest state wins); ``flush`` and ``close`` send what is held.

The child takes the newest snapshot when several are waiting (the twin runs faster than the child posts):
objects that left SUMO in between are still expired (``TrafficPublishing`` compares with what it last
published), signal changes are taken against the last state sent, so skipping a snapshot only skips an
intermediate position -- the same "newest state wins" as the publisher's merging.
"""

from __future__ import annotations

import copy
import math
import time
from pathlib import Path
from typing import Any, Self

from twin.childproc import ChildProcess, Parent, serve
from twin.traffic.publish import PublisherStats
from twin.traffic.sumo import SignalLinks, TrafficSnapshot


class TrafficPublisherProcess:
    """``publish(snapshot, extra)`` never blocks on the network; ``flush``, ``close`` and ``stats`` as
    ``UdmPublisher``'s (stats are the child's as of its last report: after ``flush`` or ``close``)."""

    def __init__(self, base_url: str, token: str, net_path: str | Path, xodr_path: str | Path,
                 links: SignalLinks, *, period_sim_s: float, validity_periods: float = 3.0,
                 min_interval_s: float | None = None, timeout_s: float = 1.0, source: str = "sumo") -> None:
        self.base_url = base_url
        # default 0: every batch of simulated time is posted, so the UDM sees 10 Hz of simulated time however
        # fast the twin runs; a wall-time floor (e.g. half the period) protects a server that cannot keep up
        self.min_interval_s = 0.0 if min_interval_s is None else max(0.0, float(min_interval_s))
        self.sent = 0  # snapshots handed to the child
        self.held = 0  # snapshots replaced by a newer one before they were handed over
        self._held: tuple[TrafficSnapshot, list[dict]] | None = None
        self._last_send = -math.inf
        self._errors = 0  # snapshots the child could not be given (it is gone)
        settings = {"base_url": base_url, "token": token, "net": str(net_path), "xodr": str(xodr_path),
                    "links": links, "period_sim_s": float(period_sim_s),
                    "validity_periods": float(validity_periods), "timeout_s": float(timeout_s), "source": source}
        self._child = ChildProcess("twin.traffic.publish_process", "the traffic publisher process", settings)

    @property
    def stats(self) -> PublisherStats:
        stats = copy.deepcopy(self._child.stats) or PublisherStats()
        if self._errors:
            stats.errors["publisher_process"] += self._errors
        return stats

    def publish(self, snapshot: TrafficSnapshot, extra: list[dict] | None = None) -> bool:
        """Hand one snapshot (and extra features, e.g. perception) to the child, or hold it if the last one
        went less than ``min_interval_s`` ago; False if the child is gone."""
        with self._child.lock:
            if self._child.closed:
                return False
            extra = (self._held[1] if self._held is not None else []) + (extra or [])
            if self._held is not None:
                self.held += 1
            self._held = (snapshot, extra)
            if time.monotonic() - self._last_send < self.min_interval_s:
                return True
            return self._send_held()

    def _send_held(self) -> bool:
        if self._held is None:
            return True
        snapshot, extra = self._held
        self._held = None
        self._last_send = time.monotonic()
        try:
            self._child.send("snapshot", snapshot, extra or None)
            self.sent += 1
            return True
        except (OSError, ValueError):
            self._errors += 1
            return False

    def flush(self, timeout_s: float = 5.0) -> bool:
        """Wait until everything published so far (a held snapshot too) was posted; False on timeout."""
        with self._child.lock:
            if not self._child.closed:
                self._send_held()
            return self._child.ask("flush", timeout_s, "flushed")

    def close(self, timeout_s: float = 5.0) -> None:
        self._child.close(timeout_s, before=self._send_held)

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


def _serve(settings: dict[str, Any], parent: Parent) -> None:
    """Read snapshots, publish the newest of those waiting, answer flush and close."""
    from twin.traffic.frames import NetFrame
    from twin.traffic.publish import TrafficPublishing, UdmPublisher

    frame = NetFrame.from_files(settings["net"], settings["xodr"])
    publisher = UdmPublisher(settings["base_url"], settings["token"], timeout_s=settings["timeout_s"])
    publishing = TrafficPublishing(publisher, frame, settings["links"], period_sim_s=settings["period_sim_s"],
                                   validity_periods=settings["validity_periods"], source=settings["source"])

    def stats() -> PublisherStats:
        with publisher._lock:  # the publisher's worker thread updates them
            return copy.deepcopy(publisher.stats)

    parent.stats = stats
    parent.ready()
    closing = None
    try:
        while closing is None:
            newest: TrafficSnapshot | None = None
            extra: list[dict] = []
            flush = None
            for message in parent.waiting(block=True):  # block until there is something to do
                kind = message[0]
                if kind == "snapshot":
                    newest = message[1]
                    extra += message[2] or []
                elif kind == "flush":
                    flush = float(message[1])
                elif kind == "close":
                    closing = float(message[1])
                    break
            if parent.gone:
                closing = 1.0  # the parent is gone: post what is queued, briefly, and stop
            if newest is not None:
                publishing.publish(newest, extra)
            elif extra:
                publisher.publish(extra)
            if flush is not None and not parent.gone:
                parent.send("flushed", publisher.flush(flush))
    finally:
        publisher.close(closing or 1.0)


if __name__ == "__main__":
    serve(_serve, "the traffic publisher process")
