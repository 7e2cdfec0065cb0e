"""The JSON ride format of the TAVF B4 smartphone recording: a list of fixes with positionLat/positionLon.

Each fix: ``positionLat``, ``positionLon`` (deg), ``speed`` (m/s), ``accuracy`` (m), ``heading`` (deg from
north), ``timeUnixMillis`` (or an ISO ``timestamp``).
"""

from __future__ import annotations

import math

from tavf_mapkit.errors import InputError
from tavf_mapkit.traces.timeparse import parse_time
from tavf_mapkit.traces.trace import Trace


def is_ride(document) -> bool:
    return isinstance(document, list) and bool(document) and isinstance(document[0], dict) \
        and "positionLat" in document[0]


def _float(value) -> float:
    try:
        return float(value) if value is not None else math.nan
    except (TypeError, ValueError):
        return math.nan


def trace_from_ride(document: list, path: str) -> Trace:
    lat, lon, t, speed, heading, accuracy = [], [], [], [], [], []
    for number, fix in enumerate(document, start=1):
        if not isinstance(fix, dict):
            raise InputError(f"fix {number} is not an object", file=path)
        lat.append(_float(fix.get("positionLat")))
        lon.append(_float(fix.get("positionLon")))
        if fix.get("timeUnixMillis") is not None:
            t.append(_float(fix["timeUnixMillis"]) / 1000.0)
        else:
            try:
                t.append(parse_time(fix.get("timestamp")))
            except ValueError as error:
                raise InputError(f"fix {number}: {error}", file=path) from None
        speed.append(_float(fix.get("speed")))
        heading.append(_float(fix.get("heading")))
        accuracy.append(_float(fix.get("accuracy")))
    return Trace.build(lat, lon, "ride-json", path, t=t, speed=speed, heading=heading, accuracy=accuracy)
