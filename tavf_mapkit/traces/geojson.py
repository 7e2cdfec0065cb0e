"""GeoJSON: Point features (properties may carry time, speed, heading, accuracy), or (Multi)LineStrings."""

from __future__ import annotations

import math

from tavf_mapkit.errors import InputError
from tavf_mapkit.traces.timeparse import parse_time
from tavf_mapkit.traces.trace import Trace

_TIME_KEYS = ("time", "timestamp", "datetime", "t")
_SPEED_KEYS = ("speed",)
_HEADING_KEYS = ("heading", "course", "bearing")
_ACCURACY_KEYS = ("accuracy", "horizontal_accuracy", "hacc")


def _property(properties: dict, keys) -> float:
    for key in keys:
        if properties.get(key) is not None:
            return properties[key]
    return math.nan


def _features(document) -> list[dict]:
    kind = document.get("type") if isinstance(document, dict) else None
    if kind == "FeatureCollection":
        return [f for f in document.get("features") or [] if isinstance(f, dict)]
    if kind == "Feature":
        return [document]
    if kind in ("Point", "MultiPoint", "LineString", "MultiLineString"):
        return [{"type": "Feature", "geometry": document, "properties": {}}]
    raise ValueError(f"not a GeoJSON object of points or lines (type {kind!r})")


def trace_from_geojson(document, path: str) -> Trace:
    try:
        features = _features(document)
    except ValueError as error:
        raise InputError(str(error), file=path) from None
    lat, lon, alt, t, speed, heading, accuracy = [], [], [], [], [], [], []

    def add(position, properties):
        if not isinstance(position, (list, tuple)) or len(position) < 2:
            raise InputError(f"a position is not [lon, lat]: {position!r}", file=path)
        lon.append(float(position[0]))
        lat.append(float(position[1]))
        alt.append(float(position[2]) if len(position) > 2 and position[2] is not None else math.nan)
        try:
            t.append(parse_time(_property(properties, _TIME_KEYS)))
        except ValueError as error:
            raise InputError(str(error), file=path) from None
        speed.append(float(_property(properties, _SPEED_KEYS)))
        heading.append(float(_property(properties, _HEADING_KEYS)))
        accuracy.append(float(_property(properties, _ACCURACY_KEYS)))

    try:
        for feature in features:
            geometry = feature.get("geometry") or {}
            properties = feature.get("properties") or {}
            kind, coordinates = geometry.get("type"), geometry.get("coordinates") or []
            if kind == "Point":
                add(coordinates, properties)
            elif kind in ("MultiPoint", "LineString"):
                for position in coordinates:
                    add(position, {})
            elif kind == "MultiLineString":
                for line in coordinates:
                    for position in line:
                        add(position, {})
    except (TypeError, ValueError):
        raise InputError("GeoJSON coordinates are not numbers", file=path) from None
    return Trace.build(lat, lon, "geojson", path, t=t, alt=alt, speed=speed, heading=heading, accuracy=accuracy)
