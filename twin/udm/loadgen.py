"""A fleet of simulated vehicles asking a UDM for their surroundings, to measure latency under load.

Each vehicle drives a random walk inside a disc around a centre and, at ``rate_hz``, asks for the
``side_m`` square around itself -- the query ``UdmClient`` makes. A vehicle has at most one request in
flight; a tick that comes round while it is still waiting is skipped and counted, so a slow server
lowers the offered load instead of piling up requests (the total is bounded by vehicles x rate x duration).

Latency is measured like the client does: request sent -> JSON parsed, with ``time.monotonic``.
"""

from __future__ import annotations

import asyncio
import ipaddress
import json
import math
import random
import time
from collections import Counter
from dataclasses import asdict, dataclass
from typing import Any
from urllib.parse import urlsplit

import httpx
import numpy as np

from twin.udm.client import HTTP_4XX, HTTP_5XX, MALFORMED, OK, transport_status
from twin.udm.model import EARTH_RADIUS_M, square_around

MAX_VEHICLES = 1000
MAX_RATE_HZ = 100.0
MAX_DURATION_S = 3600.0
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
    if parts.scheme not in ("http", "https") or not parts.hostname:
        return False
    if parts.hostname == "localhost":
        return True
    try:
        return ipaddress.ip_address(parts.hostname).is_loopback
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
        lat = self.plan.lat + math.degrees(self.north / EARTH_RADIUS_M)
        parallel_radius = EARTH_RADIUS_M * math.cos(math.radians(self.plan.lat))
        lon = self.plan.lon + math.degrees(self.east / parallel_radius)
        return lat, lon


async def _run_load(plan: LoadPlan) -> dict[str, Any]:
    rng = random.Random(plan.seed)
    latencies: list[float] = []
    object_counts: list[int] = []
    outcomes: Counter[str] = Counter()
    skipped = 0
    period = 1.0 / plan.rate_hz

    async def drive(vehicle: _Vehicle, start: float, end: float) -> None:
        nonlocal skipped
        # One client (one keep-alive connection) per vehicle, as separate cars would have; a shared pool
        # also costs httpcore time proportional to its size on every request, which the fleet would measure.
        async with httpx.AsyncClient(base_url=plan.url, timeout=plan.timeout_s, trust_env=False,
                                     limits=httpx.Limits(max_connections=1)) as client:
            tick = 0
            while (t_tick := start + tick * period) < end:
                await asyncio.sleep(max(0.0, t_tick - time.monotonic()))
                lat, lon = vehicle.step(period)
                bbox = square_around(lat, lon, plan.side_m).as_param()
                status, n_objects, latency = await _query(client, bbox)
                outcomes[status] += 1
                if status == OK:
                    latencies.append(latency)
                    object_counts.append(n_objects)
                # Ticks that passed while this vehicle waited are skipped, not queued up.
                due = math.floor((time.monotonic() - start) / period) + 1
                skipped += max(0, due - tick - 1)
                tick = max(tick + 1, due)

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


async def _query(client: httpx.AsyncClient, bbox: str) -> tuple[str, int, float]:
    """One bbox query: (status, number of objects, seconds from send to parsed JSON)."""
    t_sent = time.monotonic()
    try:
        reply = await client.get("/objects", params={"bbox": bbox})
    except httpx.HTTPError as error:
        return transport_status(error), 0, time.monotonic() - t_sent
    if reply.status_code != 200:
        return (HTTP_5XX if reply.status_code >= 500 else HTTP_4XX), 0, time.monotonic() - t_sent
    try:
        document = json.loads(reply.content)
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
