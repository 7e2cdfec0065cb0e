"""Does the twin add latency to UDM requests? The same requests, from inside a running twin and standalone.

1. In the twin: a real ``twin drive`` (random route, recording on, the UDM hook asking every ``every`` steps)
   runs until it has made ``requests`` queries. Each query's centre and publish time are kept.
2. Standalone: a plain ``UdmClient`` in a quiet process sends the same queries -- same centres, same side,
   same intervals between them -- to the same server.

Both sides are timed at the same clock points, ``time.monotonic()`` at publish (``submit``) and when the
answer has been parsed by the client (``t_received``): ``overhead_ratio`` = mean in-twin / mean standalone.
The twin additionally reports ``available`` (publish -> the simulation has the answer, at the end of the
step that polled it) and ``request`` (first byte sent -> parsed). The first answer of each side pays for the
TCP connection and is left out of both.
"""

from __future__ import annotations

import math
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from twin.udm.client import OK, UdmClient, UdmResponse
from twin.udm.loop import Answer, UdmHook, percentiles_ms

TARGET_RATIO = 1.05
WARMUP_ANSWERS = 1


@dataclass(frozen=True)
class PlannedQuery:
    offset_s: float  # after the first query, wall time
    lat: float
    lon: float
    frame: int


def run_in_twin(map_dir: Path, url: str, requests: int, *, every: int = 10, side_m: float = 200.0,
                seed: int = 0, dt: float = 0.05, timeout_s: float = 1.0,
                client: str = "process", pace: float | None = None) -> tuple[list[Answer], dict[str, Any]]:
    """A real drive with the UDM hook until ``requests`` queries were made; its answers and its metrics."""
    from twin.session.config import DriveConfig
    from twin.session.loop import Session
    from twin.session.plugins import create_hooks

    steps = (requests - 1) * every
    with tempfile.TemporaryDirectory(prefix="twin-udm-bench-") as scratch:
        plugins = {"udm": url, "udm_every": every, "udm_bbox": side_m, "udm_timeout": timeout_s, "record": True,
                   "udm_client": client}
        config = DriveConfig(map=Path(map_dir), out=Path(scratch) / "drive", random=True, duration=steps * dt,
                             seed=seed, dt=dt, plot=False, pace=pace, plugins=plugins)
        hooks = create_hooks(config.as_dict())
        udm = next(hook for hook in hooks if isinstance(hook, UdmHook))
        metrics = Session(config, hooks).run()
    return udm.answers, metrics


def plan_from(answers: Sequence[Answer]) -> list[PlannedQuery]:
    """The in-twin queries as a schedule: centres and publish times relative to the first query."""
    asked = sorted((a for a in answers if a.centre is not None), key=lambda a: a.response.t_publish)
    if not asked:
        return []
    t0 = asked[0].response.t_publish
    return [PlannedQuery(a.response.t_publish - t0, a.centre[0], a.centre[1], a.response.frame) for a in asked]


def run_standalone(url: str, plan: Sequence[PlannedQuery], *, side_m: float = 200.0,
                   timeout_s: float = 1.0) -> list[UdmResponse]:
    """Send the planned queries on schedule from this (otherwise idle) process; every answer, in order."""
    responses: list[UdmResponse] = []
    with UdmClient(url, timeout_s=timeout_s, max_retries=2) as client:
        start = time.monotonic()
        for query in plan:
            while (wait := start + query.offset_s - time.monotonic()) > 0:
                responses += client.poll()
                time.sleep(min(wait, 0.0005))
            client.submit(query.lat, query.lon, side_m, frame=query.frame, t_publish=time.monotonic())
        client.flush(timeout_s * 4 + 1.0)
        responses += client.poll()
    return sorted(responses, key=lambda response: response.t_publish)


def summary(latencies_s: Sequence[float]) -> dict[str, float] | None:
    stats = percentiles_ms(latencies_s)
    if stats is None:
        return None
    return {key: stats[key] for key in ("min", "mean", "p95", "max", "n")}


def compare(answers: Sequence[Answer], standalone: Sequence[UdmResponse]) -> dict[str, Any]:
    twin_ok = sorted((a for a in answers if a.response.status == OK), key=lambda a: a.response.t_publish)
    twin_ok = twin_ok[WARMUP_ANSWERS:]
    alone_ok = [r for r in standalone if r.status == OK][WARMUP_ANSWERS:]
    in_twin = summary([a.response.loop_latency_s for a in twin_ok])
    alone = summary([r.loop_latency_s for r in alone_ok])
    ratio = ratio_p95 = None
    if in_twin and alone and alone["mean"] > 0:
        ratio = round(in_twin["mean"] / alone["mean"], 3)
        ratio_p95 = round(in_twin["p95"] / alone["p95"], 3)
    return {
        "standalone_ms": alone,
        "in_twin_ms": in_twin,
        "in_twin_available_ms": summary([a.t_available - a.response.t_publish for a in twin_ok]),
        "in_twin_request_ms": summary([a.response.client_latency_s for a in twin_ok
                                       if a.response.client_latency_s is not None]),
        "errors": {"standalone": sum(r.status != OK for r in standalone),
                   "in_twin": sum(a.response.status != OK for a in answers)},
        "overhead_ratio": ratio,
        "overhead_ratio_p95": ratio_p95,
        "target_ratio": TARGET_RATIO,
        "meets_target": ratio is not None and ratio <= TARGET_RATIO,
    }


def run_bench(map_dir: Path, url: str, requests: int = 200, *, every: int = 10, side_m: float = 200.0,
              seed: int = 0, timeout_s: float = 1.0, client: str = "process",
              pace: float | None = None) -> dict[str, Any]:
    """The in-twin run, then the standalone run of the same pattern; the comparison as a JSON-able dict."""
    answers, metrics = run_in_twin(map_dir, url, requests, every=every, side_m=side_m, seed=seed,
                                   timeout_s=timeout_s, client=client, pace=pace)
    plan = plan_from(answers)
    standalone = run_standalone(url, plan, side_m=side_m, timeout_s=timeout_s)
    result = {"map": str(map_dir), "url": url, "requests": requests, "every": every, "bbox_m": side_m,
              "client": client, "pace": pace, **compare(answers, standalone)}
    udm = metrics.get("udm", {})
    result["twin"] = {"real_time_factor": metrics.get("real_time_factor"),
                      "sim_seconds": metrics.get("sim_seconds"), "queries": udm.get("queries"),
                      "answers": udm.get("answers"), "loop_cost_ms_per_step": udm.get("loop_cost_ms_per_step"),
                      "request_interval_ms": _mean_interval_ms(plan)}
    return result


def _mean_interval_ms(plan: Sequence[PlannedQuery]) -> float | None:
    if len(plan) < 2:
        return None
    value = 1000.0 * (plan[-1].offset_s - plan[0].offset_s) / (len(plan) - 1)
    return round(value, 3) if math.isfinite(value) else None
