"""``UdmClient`` in a child process, so a busy simulation thread cannot slow the UDM's answers down.

Why a process and not just the client's worker thread: the simulation loop is Python and holds the GIL
almost all the time. A worker thread in the same process waits for the GIL after every socket read --
up to the interpreter's switch interval (5 ms) each time -- and a 4 ms request turned into ~50 ms in a
measurement with one busy thread beside it (docs/udm-api.md, "In the loop"). In a child process the client has
an interpreter of its own; the simulation only pays for a pipe write per query and a pipe read per answer.

The interface is ``UdmClient``'s: ``submit``, ``poll``, ``stats``, ``flush``, ``close``; it never raises from
``submit``/``poll``. Times are ``time.monotonic()``, which is CLOCK_MONOTONIC, the same clock in every process
of the machine, so latencies measured in the child and publish times taken in the parent can be subtracted.
"""

from __future__ import annotations

import math
import sys
import time
from collections import deque
from typing import Any, Self

from twin.childproc import ChildProcess, Parent, serve
from twin.udm.client import INTERNAL, INVALID_FIX, ClientStats, UdmClient, UdmQuery, UdmResponse
from twin.udm.priority import normal_policy, policy_name, realtime_policy


class UdmProcessClient:
    """Non-blocking UDM queries answered by a ``UdmClient`` in a child process (same keyword arguments).

    ``realtime``: the child runs under SCHED_FIFO (twin.udm.priority.realtime_policy), so on a busy machine its
    requests and answers preempt the simulations instead of waiting for a core; where that is not permitted it
    warns once and runs at normal priority."""

    def __init__(self, base_url: str = "http://127.0.0.1:8765", *, realtime: bool = False,
                 **client_options: Any) -> None:
        self.base_url = base_url
        # returns once the child's client exists (and its policy is set), so the first query's latency does not
        # include the spawn
        self._child = ChildProcess("twin.udm.process_client", "the UDM client process",
                                   {"base_url": base_url, "options": client_options, "realtime": realtime})
        self._local: list[UdmResponse] = []  # answers made here (invalid fix, broken pipe) or read during flush
        self._local_errors: dict[str, int] = {}
        self._sent = 0  # queries handed to the child

    # --- the caller's side ---------------------------------------------------------------------------------

    def submit(self, lat: float, lon: float, side_m: float = 200.0, frame: int = -1,
               t_publish: float | None = None) -> bool:
        t_publish = time.monotonic() if t_publish is None else t_publish
        if not (math.isfinite(lat) and math.isfinite(lon) and math.isfinite(side_m) and side_m > 0):
            self._local_answer(UdmResponse(frame, t_publish, None, time.monotonic(), INVALID_FIX,
                                           error=f"invalid fix lat={lat} lon={lon} side_m={side_m}"))
            return False
        try:
            with self._child.lock:
                if self._child.closed:
                    return False
                self._child.send("query", float(lat), float(lon), float(side_m), frame, t_publish)
                self._sent += 1
            return True
        except (OSError, ValueError) as error:  # the child is gone; report it like any failed query
            self._local_answer(UdmResponse(frame, t_publish, None, time.monotonic(), INTERNAL,
                                           error=f"UDM client process: {type(error).__name__}: {error}"))
            return False

    def poll(self) -> list[UdmResponse]:
        with self._child.lock:
            responses, self._local = self._local, []
            if not self._child.closed:
                self._child.read_waiting(self._take)
                responses, self._local = responses + self._local, []
        return sorted(responses, key=lambda response: response.t_received)

    def stats(self) -> ClientStats:
        """The child's counters as of its last message. After ``close``, queries the child never reported on
        (it was stopped mid-request, or died) count as abandoned, so every sent query is accounted for."""
        with self._child.lock:
            stats = self._child.stats or ClientStats()
            errors = dict(stats.errors)
            abandoned = stats.abandoned
            if self._child.closed:
                reported = stats.ok + sum(stats.errors.values()) + stats.dropped + stats.abandoned
                abandoned += max(0, self._sent - reported)
            for status, count in self._local_errors.items():
                errors[status] = errors.get(status, 0) + count
        return ClientStats(max(stats.submitted, self._sent), stats.dropped, stats.dropped_responses,
                           stats.requests, stats.retries, stats.ok, errors, abandoned)

    def flush(self, timeout_s: float = 5.0) -> bool:
        """Wait until every query sent so far has an answer (kept for the next ``poll``); False on timeout."""
        with self._child.lock:
            return self._child.ask("flush", timeout_s, "flushed", self._take)

    def close(self, timeout_s: float = 5.0) -> None:
        self._child.close(timeout_s, self._take)

    def scheduling_policy(self) -> str | None:
        """The child's scheduling policy as the OS reports it (``fifo``, ``other``, ...); None once it ended."""
        return policy_name(self._child.process.pid) if self._child.process.poll() is None else None

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # --- internals -----------------------------------------------------------------------------------------

    def _take(self, kind: str, payload: Any) -> None:
        """A message of the child's (the lock is held): its answers are kept for the next ``poll``."""
        if kind == "answers":
            self._local += payload

    def _local_answer(self, response: UdmResponse) -> None:
        with self._child.lock:
            self._local.append(response)
            self._local_errors[response.status] = self._local_errors.get(response.status, 0) + 1


def _serve(settings: dict[str, Any], parent: Parent) -> None:
    """The child: one thread that reads queries from the pipe, asks the UDM, and sends each answer back.

    One thread on purpose: every hand-over between threads is a wake-up the OS may schedule late on a busy
    machine. Queries that arrive while a request is in flight wait in the pipe; before each request the
    pipe is drained into a bounded queue that keeps the newest ``queue_size`` (the oldest are dropped,
    as in ``UdmClient``).
    """
    reason = realtime_policy("the UDM client process") if settings.get("realtime") else None
    if reason or not settings.get("realtime"):
        normal_policy()
    if reason:  # once, on the drive's stderr (the child's is the parent's); the drive goes on
        print(f"warning: {reason}", file=sys.stderr, flush=True)
    options = dict(settings["options"])
    queue_size = max(1, int(options.pop("queue_size", 8)))
    client = UdmClient(settings["base_url"], start_worker=False, **options)
    parent.stats = client.stats
    pending: deque[UdmQuery] = deque(maxlen=queue_size)
    flush_until: list[float] = []
    parent.ready()
    with client.open_http() as http:
        try:
            while True:
                # block only when there is nothing to do; then take everything that is waiting
                closing = False
                for message in parent.waiting(block=not pending and not flush_until):
                    kind = message[0]
                    if kind == "query":
                        _, lat, lon, side_m, frame, t_publish = message
                        if len(pending) == pending.maxlen:
                            client.count("dropped")
                        pending.append(UdmQuery(frame, lat, lon, side_m, t_publish))
                        client.count("submitted")
                    elif kind == "flush":
                        flush_until.append(time.monotonic() + float(message[1]))
                    elif kind == "close":
                        closing = True
                        break
                if closing or parent.gone:
                    break
                if pending:
                    if flush_until and time.monotonic() > flush_until[0]:
                        flush_until.clear()
                        parent.send("flushed", False)
                        continue
                    parent.send("answers", [client.fetch(http, pending.popleft())])
                elif flush_until:
                    flush_until.clear()
                    parent.send("flushed", True)
        finally:
            client.count("abandoned", len(pending))


if __name__ == "__main__":
    serve(_serve, "the UDM client process")
