"""Ask a UDM what lies around the car without ever making the simulation wait for the network.

The simulation thread calls ``submit()`` (puts a query in a bounded queue and returns) and, each frame,
``poll()`` (takes whatever answers have arrived). A worker thread with its own keep-alive connection
(``twin.udm.connection``) does the HTTP, retries transient failures with bounded exponential backoff, and turns every failure into a counted
``UdmResponse`` with a status instead of an exception: a dead UDM must degrade the twin, not stop it.

Two latencies are kept per query, both from ``time.monotonic``:
- client latency: first request sent -> response parsed (what the network and server cost);
- loop latency: the frame published its fix -> the answer is available to ``poll()`` (what the car sees,
  queueing and retries included).

And two parts of the client latency, to tell where it goes: the server's own time (its ``Server-Timing`` header:
request reached the app -> answer ready) and how long this thread waited for a core during the request (Linux
schedstat; on a busy machine that wait, not the network, is most of a loopback request).
"""

from __future__ import annotations

import csv
import json
import math
import threading
import time
from collections import Counter, deque
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import IO, Any, Self

from twin.udm.connection import HttpConnection, TransportError
from twin.udm.model import InvalidObject, UdmObject, square_around

LATENCY_CSV = "udm_latency.csv"

# Response statuses. Everything except OK is an error and is counted under its own name.
OK = "ok"
TIMEOUT = "timeout"  # no answer within timeout_s
UNREACHABLE = "unreachable"  # connection refused or host unknown
NETWORK = "network"  # the connection broke mid-request
HTTP_5XX = "http_5xx"
HTTP_4XX = "http_4xx"  # our query was refused; retrying the same query cannot help
MALFORMED = "malformed"  # 200 but not a GeoJSON FeatureCollection of valid objects
INVALID_FIX = "invalid_fix"  # submit() got a NaN or infinite position; nothing was sent
INTERNAL = "internal"  # a bug on our side, caught so the worker keeps serving
RETRYABLE = frozenset({TIMEOUT, UNREACHABLE, NETWORK, HTTP_5XX})
TRANSPORT_STATUS = {"timeout": TIMEOUT, "unreachable": UNREACHABLE, "network": NETWORK}  # TransportError.kind


@dataclass(frozen=True)
class UdmQuery:
    frame: int
    lat: float
    lon: float
    side_m: float
    t_publish: float


@dataclass(frozen=True)
class UdmResponse:
    """The outcome of one query; times are ``time.monotonic()`` seconds, ``t_sent`` is the first attempt."""

    frame: int
    t_publish: float
    t_sent: float | None
    t_received: float
    status: str
    objects: tuple[UdmObject, ...] = ()
    attempts: int = 0
    http_status: int | None = None
    error: str = ""
    server_s: float | None = None  # the server's own time for the last attempt (Server-Timing), if it said
    wait_s: float | None = None  # the client thread's wait for a core while the request ran (Linux only)

    @property
    def ok(self) -> bool:
        return self.status == OK

    @property
    def client_latency_s(self) -> float | None:
        return None if self.t_sent is None else self.t_received - self.t_sent

    @property
    def loop_latency_s(self) -> float:
        return self.t_received - self.t_publish


@dataclass(frozen=True)
class ClientStats:
    submitted: int = 0
    dropped: int = 0  # queries pushed out of the full queue before they were sent
    dropped_responses: int = 0  # answers pushed out because nobody polled
    requests: int = 0  # HTTP attempts, retries included
    retries: int = 0
    ok: int = 0
    errors: dict[str, int] = field(default_factory=dict)
    abandoned: int = 0  # still queued when the client closed, never sent

    @property
    def error_count(self) -> int:
        return sum(self.errors.values())


class UdmClient:
    """Non-blocking UDM queries from a simulation loop.

    >>> with UdmClient("http://127.0.0.1:8765") as udm:
    ...     udm.submit(53.55, 9.99, frame=0)
    ...     for response in udm.poll(): ...
    """

    def __init__(
        self,
        base_url: str = "http://127.0.0.1:8765",
        *,
        timeout_s: float = 0.5,
        max_retries: int = 2,
        backoff_s: float = 0.05,
        max_backoff_s: float = 0.4,
        queue_size: int = 8,
        response_queue_size: int = 256,
        layers: tuple[int, ...] | None = None,
        types: tuple[str, ...] | None = None,
        headers: dict[str, str] | None = None,
        start_worker: bool = True,
    ) -> None:
        self.base_url = base_url
        self.timeout_s = timeout_s
        self.max_retries = max(0, max_retries)
        self.backoff_s = backoff_s
        self.max_backoff_s = max_backoff_s
        self._filters: dict[str, str] = {}
        if layers:
            self._filters["layers"] = ",".join(str(layer) for layer in layers)
        if types:
            self._filters["types"] = ",".join(types)
        self._headers = {"Accept": "application/geo+json", **(headers or {})}

        self._lock = threading.Condition()
        self._pending: deque[UdmQuery] = deque(maxlen=max(1, queue_size))
        self._done: deque[UdmResponse] = deque(maxlen=max(1, response_queue_size))
        self._in_flight = 0
        self._counts: Counter[str] = Counter()
        self._stopping = threading.Event()
        # Without the worker, the owner fetches on its own thread with open_http() and fetch().
        self._thread = threading.Thread(target=self._run, name="udm-client", daemon=True)
        if start_worker:
            self._thread.start()

    # --- the caller's side: never blocks on the network, never raises ------------------------------------

    def submit(self, lat: float, lon: float, side_m: float = 200.0, frame: int = -1,
               t_publish: float | None = None) -> bool:
        """Queue a query for the ``side_m`` square around (lat, lon); False if it was not queued."""
        try:
            t_publish = time.monotonic() if t_publish is None else t_publish
            if self._stopping.is_set():
                return False
            if not (math.isfinite(lat) and math.isfinite(lon) and math.isfinite(side_m) and side_m > 0):
                self._finish(UdmResponse(frame, t_publish, None, time.monotonic(), INVALID_FIX,
                                         error=f"invalid fix lat={lat} lon={lon} side_m={side_m}"))
                return False
            query = UdmQuery(frame, float(lat), float(lon), float(side_m), t_publish)
            with self._lock:
                if len(self._pending) == self._pending.maxlen:
                    self._counts["dropped"] += 1  # deque(maxlen) drops the oldest on append
                self._pending.append(query)
                self._counts["submitted"] += 1
                self._lock.notify_all()
            return True
        except Exception:  # noqa: BLE001 -- the caller is a simulation loop; a client bug must not end it
            return False

    def poll(self) -> list[UdmResponse]:
        """Every answer that arrived since the last poll, oldest first."""
        with self._lock:
            responses = list(self._done)
            self._done.clear()
        return responses

    def stats(self) -> ClientStats:
        with self._lock:
            counts = dict(self._counts)
        errors = {key[6:]: value for key, value in counts.items() if key.startswith("error:")}
        return ClientStats(
            submitted=counts.get("submitted", 0), dropped=counts.get("dropped", 0),
            dropped_responses=counts.get("dropped_responses", 0), requests=counts.get("requests", 0),
            retries=counts.get("retries", 0), ok=counts.get("ok", 0), errors=errors,
            abandoned=counts.get("abandoned", 0),
        )

    def flush(self, timeout_s: float = 5.0) -> bool:
        """Wait until every queued query has an answer (e.g. at the end of a run); False on timeout."""
        with self._lock:
            self._lock.wait_for(lambda: not (self._pending or self._in_flight) or not self._thread.is_alive(),
                                timeout_s)
            return not (self._pending or self._in_flight)

    def close(self, timeout_s: float = 5.0) -> None:
        """Stop the worker (an in-flight request finishes or times out first) and join it."""
        self._stopping.set()
        with self._lock:
            self._counts["abandoned"] += len(self._pending)
            self._pending.clear()
            self._lock.notify_all()
        if self._thread.ident is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout_s)

    def __enter__(self) -> Self:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 traceback: TracebackType | None) -> None:
        self.close()

    # --- the worker's side -------------------------------------------------------------------------------

    def open_http(self) -> HttpConnection:
        """The connection the worker uses (for callers that fetch synchronously with ``fetch``). It reads no
        proxy variables: they must not reroute what is meant to be a direct UDM connection."""
        return HttpConnection(self.base_url, timeout_s=self.timeout_s, headers=self._headers)

    def fetch(self, http: HttpConnection, query: UdmQuery) -> UdmResponse:
        """One query now, on the calling thread, with retries; counted like the worker's. Never raises."""
        try:
            response = self._fetch(http, query)
        except Exception as error:  # noqa: BLE001 -- reported as an INTERNAL response instead
            response = UdmResponse(query.frame, query.t_publish, None, time.monotonic(), INTERNAL,
                                   error=describe(error))
        self._count("ok" if response.ok else f"error:{response.status}")
        return response

    def _run(self) -> None:
        with self.open_http() as http:
            while True:
                with self._lock:
                    while not self._pending and not self._stopping.is_set():
                        self._lock.wait()
                    if self._stopping.is_set():
                        return
                    query = self._pending.popleft()
                    self._in_flight += 1
                try:
                    response = self._fetch(http, query)
                except Exception as error:  # noqa: BLE001 -- reported as an INTERNAL response instead
                    response = UdmResponse(query.frame, query.t_publish, None, time.monotonic(), INTERNAL,
                                           error=describe(error))
                self._finish(response, finished_query=True)

    def _fetch(self, http: HttpConnection, query: UdmQuery) -> UdmResponse:
        params = {"bbox": square_around(query.lat, query.lon, query.side_m).as_param(), **self._filters}
        waited = run_queue_wait_s()  # read outside the timed span, so reading it costs the latency nothing
        t_sent = time.monotonic()
        attempt = 0
        while True:
            attempt += 1
            self._count("requests")
            status, objects, http_status, error, server_s = self._attempt(http, params)
            if status not in RETRYABLE or attempt > self.max_retries or self._stopping.is_set():
                break
            self._count("retries")
            backoff = min(self.max_backoff_s, self.backoff_s * 2 ** (attempt - 1))
            if self._stopping.wait(backoff):
                break
        t_received = time.monotonic()
        waited_after = run_queue_wait_s()
        wait_s = None if waited is None or waited_after is None else waited_after - waited
        return UdmResponse(query.frame, query.t_publish, t_sent, t_received, status, objects, attempt,
                           http_status, error, server_s, wait_s)

    def _attempt(self, http: HttpConnection, params: dict[str, str]
                 ) -> tuple[str, tuple[UdmObject, ...], int | None, str, float | None]:
        try:
            reply = http.get("objects", params)
        except TransportError as error:
            return TRANSPORT_STATUS[error.kind], (), None, str(error)[:200], None
        server_s = server_timing_s(reply.server_timing)
        if reply.status_code >= 500:
            return HTTP_5XX, (), reply.status_code, reply.text[:200], server_s
        if reply.status_code != 200:
            return HTTP_4XX, (), reply.status_code, reply.text[:200], server_s
        try:
            return OK, objects_from_collection(json.loads(reply.body)), 200, "", server_s
        except (ValueError, InvalidObject) as error:  # JSONDecodeError is a ValueError
            return MALFORMED, (), 200, describe(error), server_s

    def count(self, key: str, amount: int = 1) -> None:
        """Add to one of the counters ``stats()`` reports (for owners that queue queries themselves)."""
        self._count(key, amount)

    def _count(self, key: str, amount: int = 1) -> None:
        with self._lock:
            self._counts[key] += amount

    def _finish(self, response: UdmResponse, finished_query: bool = False) -> None:
        with self._lock:
            if len(self._done) == self._done.maxlen:
                self._counts["dropped_responses"] += 1
            self._done.append(response)
            self._counts["ok" if response.ok else f"error:{response.status}"] += 1
            if finished_query:
                self._in_flight -= 1
            self._lock.notify_all()


def objects_from_collection(document: Any) -> tuple[UdmObject, ...]:
    """Objects from a GeoJSON FeatureCollection answer; InvalidObject if it is not one."""
    if not isinstance(document, dict) or document.get("type") != "FeatureCollection":
        raise InvalidObject("the answer is not a GeoJSON FeatureCollection")
    features = document.get("features")
    if not isinstance(features, list):
        raise InvalidObject("FeatureCollection.features is not a list")
    return tuple(UdmObject.from_feature(feature) for feature in features)


def server_timing_s(header: str) -> float | None:
    """Seconds of the ``app`` entry of a ``Server-Timing`` header (``app;dur=0.412``, in ms); None without one."""
    for entry in header.split(","):
        name, _, parameters = entry.partition(";")
        if name.strip() != "app":
            continue
        for parameter in parameters.split(";"):
            key, _, value = parameter.partition("=")
            if key.strip() == "dur":
                try:
                    duration = float(value)
                except ValueError:
                    return None
                return duration / 1000.0 if math.isfinite(duration) and duration >= 0 else None
    return None


_SCHEDSTAT = Path("/proc/thread-self/schedstat")


def run_queue_wait_s() -> float | None:
    """Seconds the calling thread has spent runnable but waiting for a core since it started (the second field
    of Linux's schedstat); None where the kernel does not say."""
    try:
        return int(_SCHEDSTAT.read_bytes().split()[1]) / 1e9
    except (OSError, IndexError, ValueError):
        return None


def describe(error: BaseException) -> str:
    return f"{type(error).__name__}: {error}"[:200]


class LatencyLog:
    """Writes one ``udm_latency.csv`` row per response; give it a run folder or a file path.

    ``step`` and ``t_available`` are filled in by a simulation loop: the step whose end took the answer and
    the monotonic time it did (``available_latency_s`` = ``t_available - t_publish``). ``server_s`` is the
    server's own time (its Server-Timing), ``client_wait_s`` the client's wait for a core during the request;
    both are parts of ``client_latency_s`` and empty when unknown.
    """

    COLUMNS = ("frame", "t_publish", "t_sent", "t_received", "client_latency_s", "loop_latency_s",
               "status", "n_objects", "error", "step", "t_available", "available_latency_s", "server_s",
               "client_wait_s")

    def __init__(self, path: str | Path) -> None:
        path = Path(path)
        self.path = path / LATENCY_CSV if path.is_dir() else path
        self._file: IO[str] = self.path.open("w", newline="", encoding="utf-8")
        self._csv = csv.writer(self._file)
        self._csv.writerow(self.COLUMNS)

    def write(self, response: UdmResponse, step: int | None = None, t_available: float | None = None) -> None:
        self._csv.writerow((
            response.frame,
            seconds(response.t_publish),
            seconds(response.t_sent),
            seconds(response.t_received),
            seconds(response.client_latency_s),
            seconds(response.loop_latency_s),
            response.status,
            len(response.objects),
            response.error,
            "" if step is None else step,
            seconds(t_available),
            seconds(None if t_available is None else t_available - response.t_publish),
            seconds(response.server_s),
            seconds(response.wait_s),
        ))

    def flush(self) -> None:
        self._file.flush()

    def write_all(self, responses: list[UdmResponse]) -> None:
        for response in responses:
            self.write(response)

    def close(self) -> None:
        self._file.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


def seconds(value: float | None) -> str:
    # Microseconds: finer than monotonic's useful resolution for network timings, short enough to read.
    return "" if value is None else f"{value:.6f}"
