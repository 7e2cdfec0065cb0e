"""CSV traces: a header names the columns (lat/latitude, lon/lng/longitude, time/timestamp, ...); without a
header the columns are lat, lon[, time]. Comma, semicolon or tab separated."""

from __future__ import annotations

import csv
import io
import math

from tavf_mapkit.errors import InputError
from tavf_mapkit.traces.timeparse import parse_time
from tavf_mapkit.traces.trace import Trace

ALIASES = {
    "lat": ("lat", "latitude", "positionlat", "lat_deg"),
    "lon": ("lon", "lng", "long", "longitude", "positionlon", "lon_deg"),
    "t": ("time", "timestamp", "t", "datetime", "time_s", "unix_time", "timeunixmillis", "time_ms"),
    "alt": ("alt", "altitude", "ele", "elevation", "height"),
    "speed": ("speed", "speed_mps", "velocity"),
    "heading": ("heading", "course", "bearing"),
    "accuracy": ("accuracy", "acc", "horizontal_accuracy", "hacc"),
}
_MILLISECONDS = ("timeunixmillis", "time_ms")


def _columns(header: list[str]) -> dict[str, int]:
    names = [name.strip().lower() for name in header]
    found = {}
    for field, aliases in ALIASES.items():
        for alias in aliases:
            if alias in names:
                found[field] = names.index(alias)
                break
    return found


def _is_number(text: str) -> bool:
    try:
        float(text)
        return True
    except ValueError:
        return False


def read_csv(path: str, text: str) -> Trace:
    sample = text[:4096]
    try:
        dialect = csv.Sniffer().sniff(sample, delimiters=",;\t")
    except csv.Error:
        dialect = csv.excel
    rows = [row for row in csv.reader(io.StringIO(text), dialect) if row and any(cell.strip() for cell in row)]
    if not rows:
        raise InputError("the trace has no fixes (empty trace)", file=path)
    first = [cell.strip() for cell in rows[0]]
    if all(_is_number(cell) for cell in first[:2]):
        columns = {"lat": 0, "lon": 1, **({"t": 2} if len(first) > 2 else {})}
        body, header_line = rows, 0
    else:
        columns = _columns(first)
        if "lat" not in columns or "lon" not in columns:
            raise InputError(f"no latitude/longitude columns in the header {first!r} (expected e.g. lat,lon,time)",
                             file=path, line=1)
        body, header_line = rows[1:], 1
    milliseconds = "t" in columns and header_line and first[columns["t"]].strip().lower() in _MILLISECONDS
    values = {field: [] for field in columns}
    for number, row in enumerate(body, start=header_line + 1):
        for field, index in columns.items():
            cell = row[index].strip() if index < len(row) else ""
            try:
                if field == "t":
                    value = parse_time(cell)
                    value = value / 1000.0 if milliseconds else value
                else:
                    value = float(cell) if cell else math.nan
            except ValueError:
                raise InputError(f"column {field!r}: {cell!r} is not a number", file=path, line=number) from None
            values[field].append(value)
    lat, lon = values.pop("lat"), values.pop("lon")
    return Trace.build(lat, lon, "csv", path, **values)
