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

import json
import math
import signal
import sys
import threading
import time
from collections import deque
from multiprocessing.connection import Connection
from typing import Any, Self

from twin.childproc import spawn_child, stop_child
from twin.udm.client import INTERNAL, INVALID_FIX, ClientStats, UdmClient, UdmQuery, UdmResponse

_START_TIMEOUT_S = 30.0


class UdmProcessClient:
    """Non-blocking UDM queries answered by a ``UdmClient`` in a child process (same keyword arguments)."""

    def __init__(self, base_url: str = "http://127.0.0.1:8765", **client_options: Any) -> None:
        self.base_url = base_url
        self._process, self._conn = spawn_child("twin.udm.process_client", base_url, json.dumps(client_options))
        self._stats = ClientStats()
        self._local: list[UdmResponse] = []  # answers made here (invalid fix, broken pipe) or read during flush
        self._local_errors: dict[str, int] = {}
        self._closed = False
        self._sent = 0  # queries handed to the child
        self._lock = threading.Lock()
        # Wait until the child's client exists, so the first query's latency does not include the spawn.
        try:
            if not self._conn.poll(_START_TIMEOUT_S):
                raise EOFError
            self._conn.recv()
        except (EOFError, OSError):
            self._process.kill()
            self._process.wait()
            raise RuntimeError("the UDM client process did not start") from None

    # --- the caller's side ---------------------------------------------------------------------------------

    def submit(self, lat: float, lon: float, side_m: float = 200.0, frame: int = -1,
               t_publish: float | None = None) -> bool:
        t_publish = time.monotonic() if t_publish is None else t_publish
        if not (math.isfinite(lat) and math.isfinite(lon) and math.isfinite(side_m) and side_m > 0):
            self._local_answer(UdmResponse(frame, t_publish, None, time.monotonic(), INVALID_FIX,
                                           error=f"invalid fix lat={lat} lon={lon} side_m={side_m}"))
            return False
        try:
            with self._lock:
                if self._closed:
                    return False
                self._conn.send(("query", float(lat), float(lon), float(side_m), frame, t_publish))
                self._sent += 1
            return True
        except (OSError, ValueError) as error:  # the child is gone; report it like any failed query
            self._local_answer(UdmResponse(frame, t_publish, None, time.monotonic(), INTERNAL,
                                           error=f"UDM client process: {type(error).__name__}: {error}"))
            return False

    def poll(self) -> list[UdmResponse]:
        with self._lock:
            responses, self._local = self._local, []
            responses += self._drain(block_for=None)
        return sorted(responses, key=lambda response: response.t_received)

    def stats(self) -> ClientStats:
        """The child's counters as of its last message. After ``close``, queries the child never reported on
        (it was stopped mid-request, or died) count as abandoned, so every sent query is accounted for."""
        with self._lock:
            stats = self._stats
            errors = dict(stats.errors)
            abandoned = stats.abandoned
            if self._closed:
                reported = stats.ok + sum(stats.errors.values()) + stats.dropped + stats.abandoned
                abandoned += max(0, self._sent - reported)
            for status, count in self._local_errors.items():
                errors[status] = errors.get(status, 0) + count
        return ClientStats(max(stats.submitted, self._sent), stats.dropped, stats.dropped_responses,
                           stats.requests, stats.retries, stats.ok, errors, abandoned)

    def flush(self, timeout_s: float = 5.0) -> bool:
        """Wait until every query sent so far has an answer (kept for the next ``poll``); False on timeout."""
        deadline = time.monotonic() + timeout_s
        with self._lock:
            if self._closed:
                return False
            try:
                self._conn.send(("flush", timeout_s))
                while True:
                    remaining = deadline - time.monotonic() + 1.0  # the child times out first
                    if remaining <= 0 or not self._conn.poll(remaining):
                        return False
                    kind, payload, stats = self._conn.recv()
                    self._stats = stats
                    if kind == "answers":
                        self._local += payload
                    elif kind == "flushed":
                        return bool(payload)
            except (OSError, EOFError, ValueError):
                return False

    def close(self, timeout_s: float = 5.0) -> None:
        with self._lock:
            if self._closed:
                return
            self._closed = True
            try:
                self._conn.send(("close", timeout_s))
                self._local += self._drain(block_for=timeout_s + 1.0)
            except (OSError, EOFError, ValueError):
                pass
            self._conn.close()
        stop_child(self._process, timeout_s)

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # --- internals -----------------------------------------------------------------------------------------

    def _drain(self, block_for: float | None) -> list[UdmResponse]:
        """Answers waiting in the pipe; with ``block_for``, read until the child says it closed."""
        responses: list[UdmResponse] = []
        try:
            while self._conn.poll(block_for or 0):
                kind, payload, stats = self._conn.recv()
                self._stats = stats
                if kind == "answers":
                    responses += payload
                elif kind == "closed":
                    break
        except (OSError, EOFError, ValueError):
            pass
        return responses

    def _local_answer(self, response: UdmResponse) -> None:
        with self._lock:
            self._local.append(response)
            self._local_errors[response.status] = self._local_errors.get(response.status, 0) + 1


def _child_main(conn: Connection, base_url: str, client_options: dict[str, Any]) -> None:
    """The child: one thread that reads queries from the pipe, asks the UDM, and sends each answer back.

    One thread on purpose: every hand-over between threads is a wake-up the OS may schedule late on a busy
    machine. Queries that arrive while a request is in flight wait in the pipe; before each request the
    pipe is drained into a bounded queue that keeps the newest ``queue_size`` (the oldest are dropped,
    as in ``UdmClient``).
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle; it closes us
    queue_size = max(1, int(client_options.pop("queue_size", 8)))
    client = UdmClient(base_url, start_worker=False, **client_options)
    pending: deque[UdmQuery] = deque(maxlen=queue_size)

    def send(kind: str, payload: Any) -> None:
        conn.send((kind, payload, client.stats()))

    def take(message: tuple) -> str:
        kind = message[0]
        if kind == "query":
            _, lat, lon, side_m, frame, t_publish = message
            if len(pending) == pending.maxlen:
                client.count("dropped")
            pending.append(UdmQuery(frame, lat, lon, side_m, t_publish))
            client.count("submitted")
        elif kind == "flush":
            flush_until.append(time.monotonic() + float(message[1]))
        return kind

    flush_until: list[float] = []
    send("ready", None)
    with client.open_http() as http:
        try:
            while True:
                try:
                    # Block only when there is nothing to do; then take everything that is waiting.
                    kind = take(conn.recv()) if not pending and not flush_until else ""
                    while kind != "close" and conn.poll(0):
                        kind = take(conn.recv())
                except (EOFError, OSError):
                    break  # the parent is gone
                if kind == "close":
                    break
                if pending:
                    if flush_until and time.monotonic() > flush_until[0]:
                        flush_until.clear()
                        send("flushed", False)
                        continue
                    send("answers", [client.fetch(http, pending.popleft())])
                elif flush_until:
                    flush_until.clear()
                    send("flushed", True)
        finally:
            client.count("abandoned", len(pending))
            try:
                send("closed", None)
            except (OSError, ValueError):
                pass
            conn.close()


if __name__ == "__main__":
    _options = json.loads(sys.argv[3])
    for _key in ("layers", "types"):
        if _options.get(_key) is not None:
            _options[_key] = tuple(_options[_key])
    _child_main(Connection(int(sys.argv[1])), sys.argv[2], _options)
