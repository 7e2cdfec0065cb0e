"""A build's map as WGS84 GeoJSON for the 2D page: the same layers ``mapkit export`` writes (one lane
polygon per lane and lane section, road marks, signals, objects), junction outlines (the mesh's junction
footprints), every validation finding and repair as a point where it happened, and the GNSS trace with its
matched path.

Geometry comes from the project's evaluator only: ``opendrive.layers`` for the layers, ``Road.lane_borders``
(opendrive/borders.py underneath) to put a finding on its lane, ``mesh.junctions.junction_footprints`` for
the outlines. Shapes are thinned for display (``TOLERANCE_M``: a vertex goes only where the shape bends more
than that), which keeps a city's page a few megabytes instead of tens.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import shapely

from tavf_mapkit.errors import InputError

STEP_M = 1.0         # sampling step of the lane and mark layers along s
TOLERANCE_M = 0.05   # display thinning (Douglas-Peucker in local metres, before the projection)
DIGITS = 7           # decimals of lon/lat: 1.1 cm


#: lane and mark features projected and encoded this many at a time by ``map_json``: as GeoJSON dicts a city's
#: layers are about ten times their JSON text (Columbus: ~300 MiB of dicts for the lanes, 60 MB of text)
FEATURE_BATCH = 20_000
#: lane samples per part of the lane sampling both layers share (``sample_lane_chunks``): ~100 MiB of samples,
#: points and features while a part is made into features
SAMPLE_CHUNK = 500_000


def map_data(odr, *, name: str, findings=(), repairs=None, match=None, attribution: str | None = None,
             step: float = STEP_M) -> dict:
    """Everything the 2D page draws, JSON-ready: {name, georeference, bounds, layers: {lanes, marks, signals,
    objects, junctions, findings, repairs, gnss, matched}}; ``findings`` are validation findings as dicts
    (rule, severity, road, lane, s, line, message), ``repairs`` the opendrive stage's ``repairs`` facts,
    ``match`` a (trace, MatchResult) pair."""
    return _map_items(odr, name, findings, repairs, match, attribution, step, batch=None)


def map_json(odr, *, name: str, findings=(), repairs=None, match=None, attribution: str | None = None,
             step: float = STEP_M, extra: dict | None = None, batch: int = FEATURE_BATCH) -> list[str]:
    """``json.dumps(map_data(...) | extra, separators=(",", ":"), allow_nan=False)`` as pieces of text (joined,
    the same text), made without holding the whole map as dicts: the lane and mark layers are projected and
    encoded ``batch`` features at a time (each feature is thinned and projected on its own, so batches change
    nothing). Pieces, so that a city's tens of megabytes are written without ever being copied into one."""
    data = _map_items(odr, name, findings, repairs, match, attribution, step, batch=batch) | (extra or {})
    return _encode_object(data)


def _map_items(odr, name, findings, repairs, match, attribution, step, batch: int | None) -> dict:
    """map_data's dict; with a ``batch``, its layers are JSON text (and the lanes and marks made in batches)."""
    georef, placed = display_georeference(odr)
    project = _Projector(georef)
    from tavf_mapkit.opendrive.layers import layer_features

    def layer(value: dict) -> dict | _JSONText:
        return value if batch is None else _JSONText([_dumps(value)])

    layers = {}
    (layers["lanes"], lane_count), (layers["marks"], _) = _lane_and_mark_layers(odr, project, step, batch)
    layers["signals"] = layer(project.collection(layer_features(odr, "signal", step)))
    layers["objects"] = layer(project.collection(layer_features(odr, "object", step)))
    layers["junctions"] = layer(project.shapes(_junction_outlines(odr, step)))
    layers["findings"] = layer(project.points(*_finding_points(odr, findings)))
    layers["repairs"] = layer(project.points(*_repair_points(odr, repairs)))
    if match is not None:
        layers.update({key: layer(value) for key, value in _gnss_layers(odr, project, *match).items()})
    lon, lat = (np.asarray(v) for v in georef.local_to_wgs84(*_corners(odr)))
    return {
        "name": name,
        "georeference": None if placed else georef.text,
        "placed_at_null_island": placed,
        "attribution": attribution,
        "bounds": [[float(lat.min()), float(lon.min())], [float(lat.max()), float(lon.max())]],
        "lane_count": lane_count,
        "layers": layers if batch is None else _JSONText(_encode_object(layers)),
    }


def _lane_and_mark_layers(odr, project: _Projector, step: float, batch: int | None):
    """((lanes, count), (marks, count)): both layers from one sampling of the lanes, made a run of lane sections
    at a time (``sample_lane_chunks``: a part's samples are the whole map's, so are the features) and fed to
    one collection per layer, so only a chunk's samples and a batch's features per layer are held."""
    from tavf_mapkit.opendrive.layers import lane_features, road_mark_features
    from tavf_mapkit.opendrive.sampling import sample_lane_chunks

    lanes, marks = _Collector(project, batch), _Collector(project, batch)
    for sampling in sample_lane_chunks(odr, step, SAMPLE_CHUNK):
        lanes.extend(lane_features(odr, step, "lane", sampling))
        marks.extend(road_mark_features(odr, step, sampling))
        del sampling
    return lanes.finish(), marks.finish()


class _Collector:
    """Features in, one layer out: a FeatureCollection dict (``batch`` None), or its JSON text made ``batch``
    features at a time (``_Projector.collection_json``), fed as the features come."""

    def __init__(self, project: _Projector, batch: int | None):
        self.project, self.batch = project, batch
        self.pending, self.parts, self.count = [], [], 0

    def extend(self, features) -> None:
        for feature in features:
            self.pending.append(feature)
            if self.batch is not None and len(self.pending) >= self.batch:
                self._flush()

    def _flush(self) -> None:
        if self.pending:
            self.parts.append(self.project.collection_piece(self.pending, bool(self.parts)))
            self.count += len(self.pending)
            self.pending = []

    def finish(self) -> tuple[dict | _JSONText, int]:
        if self.batch is None:
            value = self.project.collection(self.pending)
            return value, len(value["features"])
        self._flush()
        return _JSONText(['{"type":"FeatureCollection","features":[', *self.parts, "]}"]), self.count


def _dumps(value) -> str:
    """The page's JSON encoding (view/page.py static_map)."""
    return json.dumps(value, separators=(",", ":"), allow_nan=False)


class _JSONText(list):
    """A value already encoded (``_dumps``), as pieces of text that are written one after the other."""


def _encode_object(items: dict) -> list[str]:
    """``_dumps(items)`` as pieces, with the values that are _JSONText as they are: json.dumps writes an
    object as exactly this, its key:value pairs joined by commas."""
    pieces = ["{"]
    for k, (key, value) in enumerate(items.items()):
        pieces.append(("," if k else "") + _dumps(key) + ":")
        pieces.extend(value if isinstance(value, _JSONText) else [_dumps(value)])
    pieces.append("}")
    return pieces


def display_georeference(odr):
    """(georeference, placed): the map's own, or -- for a map without one -- the twin's placement at
    0 deg N 0 deg E (so the 2D page and a drive's lat/lon agree)."""
    from twin.sim.build import georeference_for_driving

    return georeference_for_driving(odr)


class _Projector:
    """Local x, y -> rounded lon, lat; shapes thinned in local metres first."""

    def __init__(self, georef):
        self.georef = georef

    def lonlat(self, xy: np.ndarray) -> list:
        return self.lonlat_array(xy).tolist()

    def lonlat_array(self, xy: np.ndarray) -> np.ndarray:
        lon, lat = self.georef.local_to_wgs84(xy[:, 0], xy[:, 1])
        return np.column_stack([np.round(np.atleast_1d(lon), DIGITS), np.round(np.atleast_1d(lat), DIGITS)])

    def collection(self, features) -> dict:
        """opendrive.layers features -> a GeoJSON FeatureCollection: lines and rings thinned and every vertex
        projected in one vectorised pass (a city has thousands of lanes)."""
        from tavf_mapkit.opendrive.layers import geojson_feature

        features = list(features)
        if not features:
            return {"type": "FeatureCollection", "features": []}
        counts = np.array([len(f.coordinates) for f in features], dtype=np.int64)
        xy = np.concatenate([f.coordinates[:, :2] for f in features])
        owner = np.repeat(np.arange(len(features)), counts)
        shaped = np.array([f.kind != "Point" for f in features])
        kept_xy, kept_owner = xy[~shaped[owner]], owner[~shaped[owner]]  # points as they are
        if shaped.any():
            on_shape = shaped[owner]
            rank = np.cumsum(shaped) - 1  # feature -> its index among the shaped ones
            # plain Douglas-Peucker (a fifth of the topology-preserving one's time): the shapes are only drawn
            lines = shapely.simplify(shapely.linestrings(xy[on_shape], indices=rank[owner[on_shape]]),
                                     TOLERANCE_M, preserve_topology=False)
            thin_xy, thin_rank = shapely.get_coordinates(lines, return_index=True)
            thin_owner = np.flatnonzero(shaped)[thin_rank]
            # a ring thinned below 4 vertices would no longer be a polygon: such a feature keeps its own
            polygon = np.array([f.kind == "Polygon" for f in features])
            collapsed = polygon & (np.bincount(thin_owner, minlength=len(features)) < 4)
            keep = ~collapsed[thin_owner]
            back = collapsed[owner]
            kept_xy = np.concatenate([kept_xy, thin_xy[keep], xy[back]])
            kept_owner = np.concatenate([kept_owner, thin_owner[keep], owner[back]])
        order = np.argsort(kept_owner, kind="stable")
        kept_xy, kept_owner = kept_xy[order], kept_owner[order]
        # one list of all vertices, sliced per feature: a feature's list is made by slicing, not by an array each
        vertices = self.lonlat_array(kept_xy).tolist()
        ends = np.cumsum(np.bincount(kept_owner, minlength=len(features))).tolist()
        out = [geojson_feature(feature, vertices[start:end])
               for feature, start, end in zip(features, [0, *ends[:-1]], ends)]
        return {"type": "FeatureCollection", "features": out}

    def collection_json(self, features, batch: int) -> tuple[_JSONText, int]:
        """(``_dumps(self.collection(features))`` as pieces, the number of features), ``batch`` features at a
        time: only one batch's features and dicts are held, the rest is text."""
        from itertools import islice

        features = iter(features)
        parts, count = [], 0
        while chunk := list(islice(features, batch)):
            parts.append(self.collection_piece(chunk, bool(parts)))
            count += len(chunk)
            del chunk
        return _JSONText(['{"type":"FeatureCollection","features":[', *parts, "]}"]), count

    def collection_piece(self, features: list, after: bool) -> str:
        """The features' items of ``_dumps(self.collection(features))["features"]``, without the list's
        brackets (a comma first when ``after`` others)."""
        return ("," if after else "") + _dumps(self.collection(features)["features"])[1:-1]

    def shapes(self, shapes: dict) -> dict:
        """{id: shapely (Multi)Polygon} -> outlines as GeoJSON polygons."""
        out = []
        for key, shape in shapes.items():
            polygons = []
            for part in shapely.get_parts(shapely.simplify(shape, TOLERANCE_M, preserve_topology=True)):
                rings = [part.exterior, *part.interiors]
                polygons.append([self.lonlat(shapely.get_coordinates(ring)) for ring in rings])
            if polygons:
                out.append({"type": "Feature", "properties": {"junction": key},
                            "geometry": {"type": "MultiPolygon", "coordinates": polygons}})
        return {"type": "FeatureCollection", "features": out}

    def points(self, xy: np.ndarray, properties: list[dict]) -> dict:
        coordinates = self.lonlat(xy) if len(properties) else []
        return {"type": "FeatureCollection", "features": [
            {"type": "Feature", "geometry": {"type": "Point", "coordinates": c}, "properties": p}
            for c, p in zip(coordinates, properties)]}


def _corners(odr) -> tuple[np.ndarray, np.ndarray]:
    west, south, east, north = odr.bounds(step=10.0)
    return np.array([west, east, east, west]), np.array([south, south, north, north])


def _junction_outlines(odr, step: float) -> dict:
    from tavf_mapkit.mesh.junctions import junction_footprints
    from tavf_mapkit.opendrive.sampling import sample_sections

    # only the junctions' lane sections are sampled: the outlines are made of their lanes alone
    arrays = odr.arrays
    in_junction = np.array([road.in_junction for road in odr.roads], dtype=bool)
    sections = np.flatnonzero(in_junction[arrays.section_road]) if len(arrays.section_road) else np.zeros(0, int)
    sampling = sample_sections(odr, step, sections)
    return junction_footprints(odr, sampling, np.zeros(len(arrays.lane_id), dtype=bool))


def place_on_road(odr, road_id, lane, s) -> np.ndarray | None:
    """Local (x, y) of a place named as (road, lane, s): the lane's centre at s, the reference line where no
    lane is named (or it does not exist there), the road's middle where no s is; None for an unknown road."""
    road = odr.road_by_id.get(str(road_id)) if road_id is not None else None
    if road is None:
        return None
    s = road.length / 2 if s is None else min(max(float(s), 0.0), road.length)
    t = 0.0
    if lane not in (None, 0) and road.lane_sections:
        section = int(road.section_index(s))
        borders = road.lane_borders(section, [s])
        lane = int(lane)
        inner = lane - 1 if lane > 0 else lane + 1
        if lane in borders and inner in borders:
            t = float(0.5 * (borders[lane][0] + borders[inner][0]))
    return road.surface_point([s], t)[0, :2]


def _finding_points(odr, findings) -> tuple[np.ndarray, list[dict]]:
    """Findings that name a road, at their place; each keeps rule, severity, road, lane, s, line, message."""
    xy, properties = [], []
    for finding in findings:
        finding = finding.to_dict() if hasattr(finding, "to_dict") else dict(finding)
        place = place_on_road(odr, finding.get("road"), finding.get("lane"), finding.get("s"))
        if place is None:
            continue
        xy.append(place)
        properties.append({key: finding.get(key) for key in
                           ("rule", "severity", "road", "lane", "s", "line", "message")})
    return np.reshape(np.array(xy, dtype=float), (-1, 2)), properties


def _repair_points(odr, repairs) -> tuple[np.ndarray, list[dict]]:
    """One point per repaired road (at its middle), named by the repair; repairs without roads are skipped
    (the page lists every repair with its count anyway)."""
    xy, properties = [], []
    for name, value in (repairs or {}).items() if isinstance(repairs, dict) else ():
        roads = value.get("roads") if isinstance(value, dict) else None
        for road in roads or ():
            place = place_on_road(odr, road, None, None)
            if place is not None:
                xy.append(place)
                properties.append({"repair": str(name), "road": str(road)})
    return np.reshape(np.array(xy, dtype=float), (-1, 2)), properties


def repair_counts(repairs) -> list[dict]:
    """[{repair, count}] of the opendrive stage's repairs facts (the page's table)."""
    from tavf_mapkit.pipeline.builtin.check import repair_rows

    return [{"repair": row["repair"], "count": row["count"]} for row in repair_rows(repairs or {})]


def _gnss_layers(odr, project: _Projector, trace, result) -> dict:
    """The trace's fixes (with their distance to the matched lane) and the matched lanes' centre lines."""
    from tavf_mapkit.lanegraph import LaneIndex

    fixes = project.points(np.column_stack([result.x, result.y]), [
        {"i": i, "matched": bool(result.matched[i]), "road": result.road_id[i] or None,
         "lane": int(result.lane_id[i]) if result.matched[i] else None,
         "distance_m": None if not np.isfinite(result.distance_m[i]) else round(float(result.distance_m[i]), 3)}
        for i in range(len(result))])
    route = []
    if result.lane_route:
        # the matched lanes' centre lines, from the lane graph the matcher used
        from tavf_mapkit.lanegraph import LaneGraph

        index = LaneIndex(LaneGraph.from_opendrive(odr))
        wanted = {index.keys.index(key) for key in result.lane_route if key in index.keys}
        for node in sorted(wanted):
            points = index.xy[index.node == node]
            if len(points) >= 2:
                route.append({"type": "Feature", "properties": {"lane": str(index.keys[node])},
                              "geometry": {"type": "LineString", "coordinates": project.lonlat(points)}})
    return {"gnss": fixes, "matched": {"type": "FeatureCollection", "features": route}}


def build_map_data(build, odr=None, *, step: float = STEP_M) -> dict:
    """map_data of a build folder (twin.sim.build.Build): its findings (report/validate.json), the opendrive
    stage's repairs (manifest), and the GNSS trace the check stage matched ([check] gnss_trace_path), matched
    again here (the report keeps only its statistics)."""
    from tavf_mapkit.opendrive.snapshot import load_build_map

    odr = odr if odr is not None else load_build_map(build.xodr)
    findings = []
    validate = build.path / "report" / "validate.json"
    if validate.is_file():
        try:
            findings = json.loads(validate.read_text(encoding="utf-8")).get("findings") or []
        except ValueError as error:
            raise InputError(f"unreadable JSON: {error}", file=str(validate)) from None
    stages = {stage.get("name"): stage for stage in build.manifest.get("stages") or () if isinstance(stage, dict)}
    repairs = ((stages.get("opendrive") or {}).get("facts") or {}).get("repairs")
    data = map_data(odr, name=build.name, findings=findings, repairs=repairs, match=_build_match(build, odr),
                    attribution=build.manifest.get("attribution"), step=step)
    data["repair_counts"] = repair_counts(repairs)
    data["findings_total"] = len(findings)
    return data


def _build_match(build, odr):
    """(trace, MatchResult) of the build's GNSS trace, or None (no trace in the build, or it is gone)."""
    trace_input = next((entry for entry in build.manifest.get("inputs") or ()
                        if isinstance(entry, dict) and entry.get("role") == "check.gnss_trace_path"), None)
    if trace_input is None or not Path(str(trace_input.get("path"))).is_file():
        return None
    return match_gnss(odr, trace_input["path"])


def match_gnss(odr, trace_path):
    """(trace, MatchResult) of a GNSS trace on the map, as the check stage matches it; None when it cannot be."""
    from tavf_mapkit.accuracy.matching import match_trace
    from tavf_mapkit.lanegraph import LaneGraph
    from tavf_mapkit.traces import read_trace

    try:
        trace = read_trace(trace_path)
        return trace, match_trace(odr, trace, LaneGraph.from_opendrive(odr))
    except InputError:
        return None
