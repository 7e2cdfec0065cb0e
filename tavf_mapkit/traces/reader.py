"""``read_trace(path)``: pick the reader by file type (suffix, then content)."""

from __future__ import annotations

import json
from pathlib import Path

from tavf_mapkit.errors import InputError
from tavf_mapkit.traces.trace import Trace

TRACE_FORMATS = ("gpx", "geojson", "csv", "ride-json", "rosbag")


def _text(path: Path) -> str:
    from tavf_mapkit.xmlsafe import read_input_bytes

    data = read_input_bytes(path, "a trace file")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise InputError("not a text file (expected GPX, GeoJSON, CSV or JSON)", file=str(path)) from None


def read_trace(path: str | Path) -> Trace:
    """A trace from GPX, GeoJSON, CSV (lat,lon[,time]), the JSON ride format, or a ROS 1/ROS 2 bag.

    Raises InputError (one line naming the file) for missing, unreadable, malformed or empty traces.
    """
    path = Path(path)
    name = str(path)
    from tavf_mapkit.traces.rosbag import is_bag, read_bag

    if not path.exists():
        raise InputError("file not found", file=name)
    if is_bag(path):
        return read_bag(name)
    if path.is_dir():
        raise InputError("is a directory, expected a trace file or a ROS 2 bag folder", file=name)
    suffix = path.suffix.lower()
    if suffix == ".gpx":
        from tavf_mapkit.traces.gpx import read_gpx

        return read_gpx(name)
    text = _text(path)
    stripped = text.lstrip()
    if suffix in (".json", ".geojson") or stripped[:1] in ("{", "["):
        try:
            document = json.loads(text)
        except json.JSONDecodeError as error:
            raise InputError(f"invalid JSON: {error.msg}", file=name, line=error.lineno) from None
        from tavf_mapkit.traces.ride import is_ride, trace_from_ride

        if is_ride(document):
            return trace_from_ride(document, name)
        if isinstance(document, list) and not document:
            raise InputError("the trace has no fixes (empty trace)", file=name)
        from tavf_mapkit.traces.geojson import trace_from_geojson

        return trace_from_geojson(document, name)
    if stripped.startswith("<"):
        from tavf_mapkit.traces.gpx import read_gpx

        return read_gpx(name)
    from tavf_mapkit.traces.csvtrace import read_csv

    return read_csv(name, text)
