"""GPX 1.0/1.1: track points, else route points, else waypoints (parsed with the safe XML settings)."""

from __future__ import annotations

import math

from tavf_mapkit.errors import InputError
from tavf_mapkit.traces.timeparse import parse_time
from tavf_mapkit.traces.trace import Trace


def _local(tag) -> str:
    return tag.rsplit("}", 1)[-1] if isinstance(tag, str) else ""


def _child_text(point, name: str) -> str | None:
    for child in point.iter():
        if _local(child.tag) == name and child is not point:
            return (child.text or "").strip()
    return None


def _number(text: str | None) -> float:
    try:
        return float(text) if text not in (None, "") else math.nan
    except ValueError:
        return math.nan


def read_gpx(path: str) -> Trace:
    from tavf_mapkit.xmlsafe import parse_safe, read_xml_source

    root = parse_safe(read_xml_source(path))
    if _local(root.tag) != "gpx":
        raise InputError(f"expected a GPX document (<gpx>), found <{_local(root.tag)}>", file=path)
    for kind in ("trkpt", "rtept", "wpt"):
        points = [element for element in root.iter() if _local(element.tag) == kind]
        if points:
            break
    lat, lon, t, alt, speed, heading = [], [], [], [], [], []
    for point in points:
        try:
            lat.append(float(point.get("lat")))
            lon.append(float(point.get("lon")))
        except (TypeError, ValueError):
            raise InputError("a point without numeric lat/lon", file=path, line=point.sourceline,
                             element=kind) from None
        try:
            t.append(parse_time(_child_text(point, "time")))
        except ValueError as error:
            raise InputError(str(error), file=path, line=point.sourceline, element="time") from None
        alt.append(_number(_child_text(point, "ele")))
        speed.append(_number(_child_text(point, "speed")))
        heading.append(_number(_child_text(point, "course")))
    return Trace.build(lat, lon, "gpx", path, t=t, alt=alt, speed=speed, heading=heading)
