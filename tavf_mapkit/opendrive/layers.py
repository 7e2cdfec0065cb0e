"""Vector layers of an OpenDRIVE map, after GDAL's XODR driver: reference-line, lane-border, lane-center,
lane (polygons), road-mark, object, signal. Each layer yields features (geometry in local x, y, z plus
properties); the export command transforms and writes them."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tavf_mapkit.opendrive.sampling import sample_lanes, section_samples
from tavf_mapkit.opendrive.surface import surface_points

LAYERS = ("reference-line", "lane-border", "lane-center", "lane", "road-mark", "object", "signal")


@dataclass(frozen=True)
class Feature:
    kind: str  # "LineString", "Polygon", "Point"
    coordinates: np.ndarray  # (n, 3)
    properties: dict


def _lane_runs(sampling):
    """Slices of the pair arrays, one per lane row (pairs are stored lane by lane)."""
    lane = sampling.pair_lane
    if not len(lane):
        return []
    cuts = np.flatnonzero(np.diff(lane)) + 1
    starts = np.concatenate([[0], cuts])
    ends = np.concatenate([cuts, [len(lane)]])
    return list(zip(starts, ends))


def reference_line_features(odr, step: float):
    lengths = odr.arrays.road_length
    odr.arrays.budget.check(np.arange(len(lengths)), np.maximum(lengths, 0.0) / step + 2.0,
                            f"the reference line every {step:g} m")
    for road in odr.roads:
        if road.length <= 0:
            continue
        s = np.append(np.arange(0.0, road.length, step), road.length)
        points = road.surface_point(s, 0.0)
        yield Feature("LineString", points, {"road": road.id, "name": road.name, "junction": road.junction,
                                              "length": road.length})


def lane_features(odr, step: float, layer: str, sampling=None):
    """Features of a lane layer; ``sampling``: the lanes already sampled every ``step`` m (a whole map's
    ``sample_lanes``, or a run of its lane sections, ``sample_lane_chunks``), so that several layers share one."""
    sampling = sample_lanes(odr, step) if sampling is None else sampling
    roads = odr.roads
    if layer == "lane-border":
        points = sampling.outer_border_points()
    elif layer == "lane-center":
        points = sampling.center_points()
    else:
        outer = sampling.outer_border_points()
        inner = sampling.points_at(sampling.t_inner)
    for start, end in _lane_runs(sampling):
        if end - start < 2:
            continue
        properties = {"road": roads[sampling.road_index[start]].id, "section_s0": float(sampling.section_s0[start]),
                      "lane": int(sampling.lane_id[start]), "type": str(sampling.lane_type[start])}
        if layer == "lane":
            ring = np.concatenate([inner[start:end], outer[start:end][::-1], inner[start:start + 1]])
            yield Feature("Polygon", ring, properties)
        else:
            yield Feature("LineString", points[start:end], properties)


def road_mark_features(odr, step: float, sampling=None):
    """Features of the road-mark layer; ``sampling`` as for ``lane_features``."""
    sampling = sample_lanes(odr, step) if sampling is None else sampling
    border = sampling.outer_border_points()
    for start, end in _lane_runs(sampling):
        road = odr.roads[sampling.road_index[start]]
        section = road.lane_sections[int(np.searchsorted(road.section_starts, sampling.section_s0[start],
                                                          side="right") - 1)]
        lane = section.by_id[int(sampling.lane_id[start])]
        s = sampling.s[start:end]
        marks = [m for m in lane.road_marks if m.type not in ("none", "")]
        for k, mark in enumerate(marks):
            s_end = marks[k + 1].s_offset if k + 1 < len(marks) else np.inf
            keep = (s >= mark.s_offset - 1e-9) & (s <= s_end + 1e-9)
            if keep.sum() < 2:
                continue
            yield Feature("LineString", border[start:end][keep], {
                "road": road.id, "lane": lane.id, "type": mark.type,
                "color": mark.color, "width": mark.width, "s_offset": mark.s_offset})


def _placed_points(odr, items) -> np.ndarray:
    """(n, 3) surface points of (road index, s, t, z_offset) items, all in one evaluation through the map's
    arrays (NetworkArrays.reference: the same geometry, elevation and superelevation tables as a Road's)."""
    if not items:
        return np.zeros((0, 3))
    road, s, t, h = (np.array(column) for column in zip(*items))
    x, y, z, heading, slope, superelevation, _ = odr.arrays.reference(road.astype(np.int64), s.astype(float))
    return surface_points(x, y, z, heading, slope, superelevation, t.astype(float), h.astype(float))


def object_features(odr):
    placed = [(index, road, o) for index, road in enumerate(odr.roads) for o in road.objects]
    points = _placed_points(odr, [(index, o.s, o.t, o.z_offset) for index, _, o in placed])
    for (_, road, o), point in zip(placed, points):
        yield Feature("Point", point[None, :], {
            "road": road.id, "id": o.id, "type": o.type, "name": o.name, "s": o.s, "t": o.t,
            "length": o.length, "width": o.width, "height": o.height, "radius": o.radius, "hdg": o.hdg})


def signal_features(odr):
    placed = [(index, road, signal) for index, road in enumerate(odr.roads) for signal in road.signals]
    points = _placed_points(odr, [(index, signal.s, signal.t, signal.z_offset) for index, _, signal in placed])
    for (_, road, signal), point in zip(placed, points):
        yield Feature("Point", point[None, :], {
            "road": road.id, "id": signal.id, "type": signal.type, "subtype": signal.subtype,
            "country": signal.country, "dynamic": signal.dynamic, "value": signal.value, "name": signal.name,
            "s": signal.s, "t": signal.t, "orientation": signal.orientation})


def layer_features(odr, layer: str, step: float):
    if layer == "reference-line":
        return reference_line_features(odr, step)
    if layer in ("lane-border", "lane-center", "lane"):
        return lane_features(odr, step, layer)
    if layer == "road-mark":
        return road_mark_features(odr, step)
    if layer == "object":
        return object_features(odr)
    if layer == "signal":
        return signal_features(odr)
    raise ValueError(f"unknown layer {layer!r}; choose from {', '.join(LAYERS)}")


__all__ = ["LAYERS", "Feature", "layer_features", "section_samples"]


def json_properties(properties: dict) -> dict:
    """A feature's properties as JSON takes them: numpy scalars as Python numbers, non-finite floats as None
    (JSON has no NaN)."""
    out = {}
    for key, value in properties.items():
        if isinstance(value, (np.floating, float)):
            value = float(value) if np.isfinite(value) else None
        elif isinstance(value, np.integer):
            value = int(value)
        elif isinstance(value, np.bool_):
            value = bool(value)
        out[key] = value
    return out


def geojson_feature(feature: Feature, coordinates: list) -> dict:
    """A GeoJSON Feature of a layer feature, with its vertices as given (already projected and rounded)."""
    if feature.kind == "Point":
        geometry = {"type": "Point", "coordinates": coordinates[0]}
    elif feature.kind == "Polygon":
        geometry = {"type": "Polygon", "coordinates": [coordinates]}
    else:
        geometry = {"type": "LineString", "coordinates": coordinates}
    return {"type": "Feature", "geometry": geometry, "properties": json_properties(feature.properties)}
