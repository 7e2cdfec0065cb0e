"""A fleet of simulated vehicles asking a UDM for their surroundings, to measure latency under load.

Each vehicle drives a random walk inside a disc around a centre and, at ``rate_hz``, asks for the
``side_m`` square around itself -- the query ``UdmClient`` makes. A vehicle has at most one request in
flight; a tick that comes round while it is still waiting is skipped and counted, so a slow server
lowers the offered load instead of piling up requests (the total is bounded by vehicles x rate x duration).

Latency is measured like the client does: request sent -> JSON parsed, with ``time.monotonic``.

Why not httpx here: the instrument must cost far less than what it measures. httpx's async client spends
several times the server's CPU per request (its pool and async-library detection run on every call), and
on a small machine the fleet then measures itself. Each vehicle instead keeps one keep-alive HTTP/1.1
connection and speaks the few lines of the protocol a GET needs.
"""

from __future__ import annotations

import asyncio
import ipaddress
import json
import math
import random
import ssl
import time
from collections import Counter
from dataclasses import asdict, dataclass
from typing import Any
from urllib.parse import urlencode, urlsplit

import numpy as np

from twin.udm.client import HTTP_4XX, HTTP_5XX, MALFORMED, NETWORK, OK, TIMEOUT, UNREACHABLE
from twin.udm.model import EARTH_RADIUS_M, square_around

MAX_VEHICLES = 1000
MAX_RATE_HZ = 100.0
MAX_DURATION_S = 3600.0
MAX_RESPONSE_BYTES = 64 * 1024 * 1024
HAMBURG = (53.55, 9.99)


@dataclass(frozen=True)
class LoadPlan:
    url: str
    vehicles: int = 50
    rate_hz: float = 10.0
    duration_s: float = 60.0
    lat: float = HAMBURG[0]
    lon: float = HAMBURG[1]
    area_radius_m: float = 3000.0
    side_m: float = 200.0
    timeout_s: float = 1.0
    seed: int = 0

    def check(self) -> None:
        """Raise ValueError when the plan is outside the bounds that keep a load test a test."""
        if urlsplit(self.url).scheme not in ("http", "https") or not urlsplit(self.url).hostname:
            raise ValueError(f"url {self.url!r} is not an http(s) URL")
        if not 1 <= self.vehicles <= MAX_VEHICLES:
            raise ValueError(f"vehicles must be 1..{MAX_VEHICLES}")
        if not 0 < self.rate_hz <= MAX_RATE_HZ:
            raise ValueError(f"rate must be more than 0 and at most {MAX_RATE_HZ:g} Hz")
        if not 0 < self.duration_s <= MAX_DURATION_S:
            raise ValueError(f"duration must be more than 0 and at most {MAX_DURATION_S:g} s")
        if not (self.side_m > 0 and self.area_radius_m >= 0 and self.timeout_s > 0):
            raise ValueError("side, area radius and timeout must be positive")


def is_loopback_url(url: str) -> bool:
    """True for http(s) URLs on 127.0.0.0/8, ::1 or localhost -- no name resolution involved."""
    parts = urlsplit(url)
    return parts.scheme in ("http", "https") and is_loopback_host(parts.hostname or "")


def is_loopback_host(host: str) -> bool:
    """True for 127.0.0.0/8, ::1 and localhost; names are not resolved (a DNS answer can change)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def run_load(plan: LoadPlan) -> dict[str, Any]:
    """Drive the fleet for ``plan.duration_s`` and report counts and latency percentiles (milliseconds)."""
    plan.check()
    return asyncio.run(_run_load(plan))


class _Vehicle:
    """A random walk in local east/north metres around the plan's centre, bouncing off the disc's rim."""

    def __init__(self, plan: LoadPlan, rng: random.Random) -> None:
        radius = plan.area_radius_m * math.sqrt(rng.random())  # sqrt: uniform over the disc, not the radius
        angle = rng.uniform(0.0, 2 * math.pi)
        self.east, self.north = radius * math.cos(angle), radius * math.sin(angle)
        self.heading = rng.uniform(0.0, 2 * math.pi)
        self.speed = rng.uniform(5.0, 15.0)
        self.plan, self.rng = plan, rng

    def step(self, dt: float) -> tuple[float, float]:
        self.heading += self.rng.gauss(0.0, 0.1)
        self.east += self.speed * dt * math.sin(self.heading)
        self.north += self.speed * dt * math.cos(self.heading)
        if math.hypot(self.east, self.north) > self.plan.area_radius_m:
            self.heading += math.pi
        parallel_radius = EARTH_RADIUS_M * math.cos(math.radians(self.plan.lat))
        lat = self.plan.lat + math.degrees(self.north / EARTH_RADIUS_M)
        lon = self.plan.lon + math.degrees(self.east / parallel_radius)
        return lat, lon


class _ConnectFailed(Exception):
    """The TCP (or TLS) connection could not be opened: the UDM is unreachable."""


class _Connection:
    """One keep-alive HTTP/1.1 connection that can GET and read a Content-Length or chunked body."""

    def __init__(self, url: str, tls: ssl.SSLContext | None) -> None:
        parts = urlsplit(url)
        self.host = parts.hostname or ""
        self.port = parts.port or (443 if parts.scheme == "https" else 80)
        self.host_header = parts.netloc
        self.prefix = parts.path.rstrip("/")
        self.tls = tls if parts.scheme == "https" else None
        self.reader: asyncio.StreamReader | None = None
        self.writer: asyncio.StreamWriter | None = None

    async def get(self, path: str, params: dict[str, str]) -> tuple[int, bytes]:
        """(status code, body); raises _ConnectFailed, OSError, IncompleteReadError or ValueError."""
        if self.writer is None or self.writer.is_closing():
            try:
                self.reader, self.writer = await asyncio.open_connection(self.host, self.port, ssl=self.tls)
            except OSError as error:
                raise _ConnectFailed(str(error)) from error
        assert self.reader is not None
        target = f"{self.prefix}{path}?{urlencode(params)}"
        self.writer.write(f"GET {target} HTTP/1.1\r\nHost: {self.host_header}\r\n"
                          "Accept: application/geo+json\r\n\r\n".encode("ascii"))
        head = await self.reader.readuntil(b"\r\n\r\n")
        status_line, *header_lines = head.decode("latin-1").split("\r\n")
        status = int(status_line.split(" ", 2)[1])
        headers = {}
        for line in header_lines:
            if ":" in line:
                name, value = line.split(":", 1)
                headers[name.strip().lower()] = value.strip()
        if "chunked" in headers.get("transfer-encoding", "").lower():
            body = await self._read_chunked()
        else:
            length = int(headers.get("content-length", "0"))
            if length > MAX_RESPONSE_BYTES:
                raise ValueError(f"response of {length} bytes is too large")
            body = await self.reader.readexactly(length)
        if headers.get("connection", "").lower() == "close":
            self.close()
        return status, body

    async def _read_chunked(self) -> bytes:
        assert self.reader is not None
        chunks, total = [], 0
        while True:
            size = int((await self.reader.readuntil(b"\r\n")).split(b";")[0], 16)
            if size == 0:  # the last chunk: optional trailer lines, then an empty line
                while (await self.reader.readuntil(b"\r\n")) != b"\r\n":
                    pass
                return b"".join(chunks)
            total += size
            if total > MAX_RESPONSE_BYTES:
                raise ValueError("chunked response is too large")
            chunks.append((await self.reader.readexactly(size + 2))[:-2])  # each chunk ends in CRLF

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()
        self.reader = self.writer = None


async def _run_load(plan: LoadPlan) -> dict[str, Any]:
    rng = random.Random(plan.seed)
    latencies: list[float] = []
    object_counts: list[int] = []
    outcomes: Counter[str] = Counter()
    skipped = 0
    period = 1.0 / plan.rate_hz
    tls = ssl.create_default_context() if plan.url.startswith("https") else None

    async def drive(vehicle: _Vehicle, start: float, end: float) -> None:
        nonlocal skipped
        connection = _Connection(plan.url, tls)
        tick = 0
        try:
            while (t_tick := start + tick * period) < end:
                await asyncio.sleep(max(0.0, t_tick - time.monotonic()))
                lat, lon = vehicle.step(period)
                bbox = square_around(lat, lon, plan.side_m).as_param()
                status, n_objects, latency = await _query(connection, bbox, plan.timeout_s)
                outcomes[status] += 1
                if status == OK:
                    latencies.append(latency)
                    object_counts.append(n_objects)
                # Ticks that passed while this vehicle waited are skipped, not queued up.
                due = math.floor((time.monotonic() - start) / period) + 1
                skipped += max(0, due - tick - 1)
                tick = max(tick + 1, due)
        finally:
            connection.close()

    vehicles = [_Vehicle(plan, rng) for _ in range(plan.vehicles)]
    begin = time.monotonic() + 0.05
    end = begin + plan.duration_s
    # Spread the vehicles' phases over one period, as independent cars would be.
    await asyncio.gather(*(drive(v, begin + rng.uniform(0.0, period), end) for v in vehicles))
    elapsed = time.monotonic() - begin

    requests = sum(outcomes.values())
    errors = {status: count for status, count in sorted(outcomes.items()) if status != OK}
    return {
        "url": plan.url,
        "plan": asdict(plan),
        "requests": requests,
        "ok": outcomes[OK],
        "errors": sum(errors.values()),
        "errors_by_kind": errors,
        "skipped_ticks": skipped,
        "achieved_rate_hz": round(requests / elapsed, 1) if elapsed > 0 else 0.0,
        "latency_ms": latency_summary_ms(latencies),
        "objects_per_response": round(float(np.mean(object_counts)), 1) if object_counts else 0.0,
    }


async def _query(connection: _Connection, bbox: str, timeout_s: float) -> tuple[str, int, float]:
    """One bbox query: (status, number of objects, seconds from send to parsed JSON)."""
    t_sent = time.monotonic()
    try:
        async with asyncio.timeout(timeout_s):
            code, body = await connection.get("/objects", {"bbox": bbox})
    except TimeoutError:
        connection.close()  # the late answer would otherwise be read as the next query's
        return TIMEOUT, 0, time.monotonic() - t_sent
    except _ConnectFailed:
        connection.close()
        return UNREACHABLE, 0, time.monotonic() - t_sent
    except (OSError, asyncio.IncompleteReadError, asyncio.LimitOverrunError, ValueError, IndexError):
        connection.close()
        return NETWORK, 0, time.monotonic() - t_sent
    if code != 200:
        return (HTTP_5XX if code >= 500 else HTTP_4XX), 0, time.monotonic() - t_sent
    try:
        document = json.loads(body)
        features = document["features"]
        if document.get("type") != "FeatureCollection" or not isinstance(features, list):
            raise ValueError("not a FeatureCollection")
    except (ValueError, KeyError, TypeError, AttributeError):
        return MALFORMED, 0, time.monotonic() - t_sent
    return OK, len(features), time.monotonic() - t_sent


def latency_summary_ms(latencies_s: list[float]) -> dict[str, float | None]:
    if not latencies_s:
        return {"p50": None, "p95": None, "max": None, "mean": None}
    values = np.asarray(latencies_s) * 1000.0
    return {
        "p50": round(float(np.percentile(values, 50)), 3),
        "p95": round(float(np.percentile(values, 95)), 3),
        "max": round(float(values.max()), 3),
        "mean": round(float(values.mean()), 3),
    }
