"""The sweep's table: one row per run from what that run wrote (metrics.json; p99 of the UDM request latency
from its udm_latency.csv, whose p50 and p95 metrics.json already holds), sweep.csv / sweep.json, and the worst
runs named."""

from __future__ import annotations

import csv
import io
import json

import numpy as np

COLUMNS = ("seed", "status", "exit", "resets", "collisions", "off_road_s", "red_light_violations",
           "trace_distance_mean_m", "distance_m", "udm_p50_ms", "udm_p95_ms", "udm_p99_ms", "udm_errors",
           "real_time_factor", "wall_s", "error")
# what a run's drive did, as opposed to how fast this machine was: equal for equal seeds on any worker
DRIVE_COLUMNS = ("status", "exit", "resets", "collisions", "off_road_s", "red_light_violations",
                 "trace_distance_mean_m", "distance_m")
WORST = 5


def run_row(result: dict) -> dict:
    """A table row of one ``runs.drive_once`` result."""
    files = result.get("files", {})
    metrics = {}
    if "metrics.json" in files:
        metrics = json.loads(files["metrics.json"].decode("utf-8"))
    udm = metrics.get("udm") or {}
    request = ((udm.get("latency_ms") or {}).get("request")) or {}
    return {
        "seed": result["seed"], "status": result["status"], "exit": result["exit"],
        "resets": metrics.get("resets"), "collisions": metrics.get("collisions"),
        "off_road_s": metrics.get("off_road_seconds"),
        "red_light_violations": metrics.get("red_light_violations"),  # recorded only with --traffic
        "trace_distance_mean_m": metrics.get("trace_distance_mean_m"),  # only for --route drives
        "distance_m": metrics.get("distance_m"),
        "udm_p50_ms": request.get("p50"), "udm_p95_ms": request.get("p95"),
        "udm_p99_ms": _p99_ms(files.get("udm_latency.csv")) if udm else None,
        "udm_errors": udm.get("error_count") if udm else None,
        "real_time_factor": metrics.get("real_time_factor"), "wall_s": result.get("wall_s"),
        "error": result.get("error") or "",
    }


def _p99_ms(data: bytes | None) -> float | None:
    if not data:
        return None
    rows = csv.DictReader(io.StringIO(data.decode("utf-8")))
    values = [float(row["client_latency_s"]) for row in rows
              if row.get("status") == "ok" and row.get("client_latency_s") not in (None, "")]
    return round(float(np.percentile(np.asarray(values) * 1000.0, 99)), 3) if values else None


def badness(row: dict) -> tuple:
    """Sort key, worst first: failed runs, then collisions, resets, red lights, off-road seconds, UDM p95."""
    return (row["status"] != "ok", row["collisions"] or 0, row["resets"] or 0, row["red_light_violations"] or 0,
            row["off_road_s"] or 0.0, row["udm_p95_ms"] or 0.0, -row["seed"])


def worst_runs(rows: list[dict], count: int = WORST) -> list[dict]:
    """The runs that went wrong (failed, collided, reset, ran a red light, left the road), worst first."""
    bad = [row for row in rows if badness(row)[:5] != (False, 0, 0, 0, 0.0)]
    return sorted(bad, key=badness, reverse=True)[:count]


def describe(row: dict) -> str:
    if row["status"] != "ok":
        return f"seed {row['seed']}: {row['status']} ({row['error']})"
    parts = [f"{row[key]} {label}" for key, label in (("collisions", "collisions"), ("resets", "resets"),
                                                       ("red_light_violations", "red-light violations"))
             if row[key]]
    if row["off_road_s"]:
        parts.append(f"{row['off_road_s']:.2f} s off-road")
    return f"seed {row['seed']}: " + ", ".join(parts)


def summary(rows: list[dict], build: str, options: dict, seconds: float, workers: int | str) -> dict:
    ok = [row for row in rows if row["status"] == "ok"]

    def total(key):
        return sum(row[key] or 0 for row in ok)

    latency = [row["udm_p95_ms"] for row in ok if row["udm_p95_ms"] is not None]
    worst = worst_runs(rows)
    return {
        "build": build, "options": options, "runs": len(rows), "ok": len(ok),
        "failed": sum(row["status"] == "failed" for row in rows),
        "timed_out": sum(row["status"] == "timeout" for row in rows),
        "collisions": total("collisions"), "resets": total("resets"),
        "red_light_violations": total("red_light_violations"),
        "off_road_s": round(sum(row["off_road_s"] or 0.0 for row in ok), 3),
        "udm_p95_ms_worst": max(latency) if latency else None,
        "worst": [{"seed": row["seed"], "why": describe(row)} for row in worst],
        "seconds": round(seconds, 3), "workers": workers,
    }


def csv_text(rows: list[dict]) -> str:
    out = io.StringIO()
    writer = csv.DictWriter(out, fieldnames=COLUMNS, lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({key: "" if row[key] is None else row[key] for key in COLUMNS})
    return out.getvalue()
