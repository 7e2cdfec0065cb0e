"""Accuracy baselines: named measurements on the real data, their committed values and tolerances.

A baseline file (package data tavf_mapkit/data/baselines/accuracy.json) maps each measurement to its metrics:
``{"value": v, "tolerance": t, "better": "lower" | "higher" | "equal"}``. A metric regresses when it is
worse than ``value`` by more than ``tolerance`` ("equal": differs by more). Values change only through
``mapkit baseline refresh``, which recomputes them and keeps tolerances; tests never write the file.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from tavf_mapkit.data import data_path
from tavf_mapkit.errors import InputError

# Package data, so `mapkit baseline show` works in an installed wheel; in a development checkout (editable
# install) this is the tracked file that `mapkit baseline refresh` rewrites and the regression test reads.
BASELINE_FILE = data_path("baselines", "accuracy.json")


@dataclass(frozen=True)
class Measurement:
    name: str
    needs: tuple[str, ...]           # input roles: jungfernstieg_xodr, tavf_dlr_xodr, dlr_net, ride
    description: str
    run: Callable[[dict], dict]      # {role: Path} -> {metric: number}
    defaults: dict                   # metric -> (tolerance, better) for a new baseline file


def _match_ride(inputs: dict) -> dict:
    from tavf_mapkit.accuracy.matching import match_trace
    from tavf_mapkit.opendrive import load_opendrive
    from tavf_mapkit.traces import read_trace

    stats = match_trace(load_opendrive(inputs["tavf_dlr_xodr"]), read_trace(inputs["ride"])).stats()
    return {key: stats[key] for key in ("median_m", "mean_m", "p95_m", "matched_fraction", "floor_mean_m")}


def _compare_metrics(build: Path, reference: Path) -> dict:
    from tavf_mapkit.accuracy.compare import compare_networks

    report = compare_networks(build, reference).to_dict()
    fit = report["fitted_transform"] or {}
    return {
        "offset_median_m": report["offset"]["median_m"], "offset_p95_m": report["offset"]["p95_m"],
        "paired_fraction": report["offset"]["paired_fraction"],
        "precision_2m": report["precision"]["2"], "recall_2m": report["recall"]["2"],
        "recall_3m": report["recall"]["3"], "hausdorff_lanes_m": report["hausdorff_m"]["lanes"],
        "transform_dx_m": fit.get("dx"), "transform_dy_m": fit.get("dy"),
        "overlap_km2": report["overlap"]["area_km2"],
    }


_COMPARE_DEFAULTS = {
    "offset_median_m": (0.05, "lower"), "offset_p95_m": (0.2, "lower"), "paired_fraction": (0.01, "higher"),
    "precision_2m": (0.01, "higher"), "recall_2m": (0.01, "higher"), "recall_3m": (0.01, "higher"),
    "hausdorff_lanes_m": (2.0, "lower"), "transform_dx_m": (0.05, "equal"), "transform_dy_m": (0.05, "equal"),
    "overlap_km2": (0.02, "equal"),
}

MEASUREMENTS = {m.name: m for m in (
    Measurement(
        "match-trace/tavf-dlr/gnss-ride-b4", ("tavf_dlr_xodr", "ride"),
        "the shared 1 Hz smartphone ride (thomas.json) map-matched to a build of DLR's TAVF network",
        _match_ride,
        {"median_m": (0.15, "lower"), "mean_m": (0.25, "lower"), "p95_m": (0.75, "lower"),
         "matched_fraction": (0.01, "higher"), "floor_mean_m": (0.05, "equal")}),
    Measurement(
        "compare/jungfernstieg/dlr-net", ("jungfernstieg_xodr", "dlr_net"),
        "the Jungfernstieg OSM build against DLR's hand-edited SUMO network, where both have roads",
        lambda inputs: _compare_metrics(inputs["jungfernstieg_xodr"], inputs["dlr_net"]), _COMPARE_DEFAULTS),
    Measurement(
        "compare/tavf-dlr/dlr-net", ("tavf_dlr_xodr", "dlr_net"),
        "a build of DLR's network against the network itself: netconvert + our georeference chain",
        lambda inputs: _compare_metrics(inputs["tavf_dlr_xodr"], inputs["dlr_net"]), _COMPARE_DEFAULTS),
)}


def load_baselines(path: Path = BASELINE_FILE) -> dict:
    try:
        return json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError("no baseline file; create it with `mapkit baseline refresh`", file=str(path)) from None
    except json.JSONDecodeError as error:
        raise InputError(f"invalid JSON: {error.msg}", file=str(path), line=error.lineno) from None


def regressions(name: str, measured: dict, baselines: dict) -> list[str]:
    """Human-readable lines for every metric of ``name`` worse than its baseline beyond the tolerance."""
    entry = baselines["measurements"].get(name)
    if entry is None:
        return [f"{name}: no baseline (run `mapkit baseline refresh`)"]
    problems = []
    for metric, spec in entry["metrics"].items():
        value, tolerance, better = spec["value"], spec["tolerance"], spec["better"]
        current = measured.get(metric)
        if value is None or current is None:
            if value != current:
                problems.append(f"{name}: {metric} is {current}, baseline {value}")
            continue
        worse = {"lower": current > value + tolerance, "higher": current < value - tolerance,
                 "equal": abs(current - value) > tolerance}[better]
        if worse:
            problems.append(f"{name}: {metric} = {current} is worse than the baseline {value} "
                            f"(tolerance {tolerance}, {better} is better)")
    return problems


def refreshed(measured: dict[str, dict], previous: dict | None, note: str) -> dict:
    """A new baseline document: measured values, tolerances and directions kept from ``previous``."""
    from tavf_mapkit import __version__

    old = (previous or {}).get("measurements", {})
    document = {
        "about": ("Accuracy baselines checked by tests/test_accuracy_regression.py. A metric fails CI when it is "
                  "worse than 'value' by more than 'tolerance' ('better': which direction is an improvement; "
                  "'equal': any change beyond the tolerance). Refresh ONLY with `mapkit baseline refresh` "
                  "after a deliberate change, and say why in the commit."),
        "mapkit": __version__,
        "note": note,
        "measurements": {},
    }
    for name, metrics in measured.items():
        measurement = MEASUREMENTS[name]
        kept = old.get(name, {}).get("metrics", {})
        document["measurements"][name] = {
            "description": measurement.description,
            "metrics": {
                metric: {"value": value,
                         "tolerance": kept.get(metric, {}).get("tolerance", measurement.defaults[metric][0]),
                         "better": kept.get(metric, {}).get("better", measurement.defaults[metric][1])}
                for metric, value in metrics.items()
            },
        }
    return document
