"""Road networks for comparison: OpenDRIVE or SUMO, each placed through its own georeference into one
metric CRS (a transverse Mercator centred on the build, so east/north there are true east/north).

A Network holds lane centre lines, road centre lines (the middle of each road's driving lanes), junction
positions and the connectivity of its lane graph.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyproj

from tavf_mapkit.accuracy.polylines import LineSamples, line_headings, resample_polylines, sample_weights
from tavf_mapkit.errors import InputError
from tavf_mapkit.opendrive.budget import MAX_POINTS
from tavf_mapkit.opendrive.plausibility import off_earth, vertex_problem

_WGS84 = pyproj.CRS.from_epsg(4326)
LANE_TYPE_GROUPS = {"walking": "sidewalk", "bidirectional": "driving", "entry": "driving", "exit": "driving",
                    "onRamp": "driving", "offRamp": "driving", "connectingRamp": "driving"}


@dataclass(frozen=True, eq=False)
class Network:
    path: str
    kind: str                # "opendrive" or "sumo"
    lanes: LineSamples       # lane centre lines in the common CRS
    lanes_lonlat: tuple[np.ndarray, np.ndarray]
    roads: LineSamples       # road centre lines (driving lanes only)
    roads_lonlat: tuple[np.ndarray, np.ndarray]
    junctions_xy: np.ndarray   # (n, 2)
    junctions_lonlat: np.ndarray
    largest_scc_share: float   # of the driving lane length
    dead_ends: int             # driving lanes with no successor


class CommonFrame:
    """WGS84 <-> the comparison CRS (tmerc centred on a point, scale 1)."""

    def __init__(self, lon0: float, lat0: float):
        self.proj = (f"+proj=tmerc +lat_0={lat0:.7f} +lon_0={lon0:.7f} +k=1 +x_0=0 +y_0=0 +ellps=WGS84 "
                     "+units=m +no_defs")
        crs = pyproj.CRS.from_proj4(self.proj)
        self._forward = pyproj.Transformer.from_crs(_WGS84, crs, always_xy=True)
        self._inverse = pyproj.Transformer.from_crs(crs, _WGS84, always_xy=True)

    def from_lonlat(self, lon, lat):
        return self._forward.transform(np.asarray(lon, dtype=float), np.asarray(lat, dtype=float))

    def to_lonlat(self, x, y):
        return self._inverse.transform(np.asarray(x, dtype=float), np.asarray(y, dtype=float))


def _samples(frame, lon, lat, line, lane_type, reverse=None) -> LineSamples:
    x, y = frame.from_lonlat(lon, lat)
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    heading = line_headings(x, y, line)
    if reverse is not None:
        heading = np.where(reverse, heading + np.pi, heading)
    return LineSamples(x, y, line, lane_type, heading, sample_weights(x, y, line))


# ------------------------------------------------------------------ OpenDRIVE

def load_opendrive_network(path: str, frame_for=None, step: float = 0.5, odr=None):
    """(Network, frame) of an OpenDRIVE file; ``frame_for(lon, lat)`` makes the common frame if None given."""
    from tavf_mapkit.lanegraph import LaneGraph
    from tavf_mapkit.opendrive import load_opendrive
    from tavf_mapkit.opendrive.sampling import sample_lanes

    odr = odr or load_opendrive(path)
    if odr.georeference is None:
        raise InputError("has no geoReference, so it cannot be placed next to another network", file=str(path))
    sampling = sample_lanes(odr, step)
    centre = sampling.center_points(with_height=False)
    lon, lat = odr.georeference.local_to_wgs84(centre[:, 0], centre[:, 1])
    lon, lat = np.asarray(lon), np.asarray(lat)
    frame = frame_for(lon, lat) if callable(frame_for) else frame_for
    lht = np.array([road.rule == "LHT" for road in odr.roads], dtype=bool)
    reverse = (sampling.lane_id > 0) != lht[sampling.road_index]
    lane_type = np.array([LANE_TYPE_GROUPS.get(t, t) for t in sampling.lane_type], dtype=object)
    lanes = _samples(frame, lon, lat, sampling.pair_lane, lane_type, reverse)

    # road centre: the middle between the outermost borders of the driving lanes at each sample (junction
    # interiors left out, as SUMO's internal lanes are)
    in_junction = np.array([road.in_junction for road in odr.roads], dtype=bool)
    driving = (lane_type == "driving") & ~in_junction[sampling.road_index]
    n_samples = len(sampling.sample_s)
    low = np.full(n_samples, np.inf)
    high = np.full(n_samples, -np.inf)
    sample = sampling.pair_sample[driving]
    np.minimum.at(low, sample, np.minimum(sampling.t_inner, sampling.t_outer)[driving])
    np.maximum.at(high, sample, np.maximum(sampling.t_inner, sampling.t_outer)[driving])
    has = np.isfinite(low)
    t_mid = 0.5 * (low[has] + high[has])
    heading = sampling.heading[has]
    rx = sampling.ref_x[has] - t_mid * np.sin(heading)
    ry = sampling.ref_y[has] + t_mid * np.cos(heading)
    road_lon, road_lat = (np.asarray(v) for v in odr.georeference.local_to_wgs84(rx, ry))
    road_line = sampling.sample_section[has]
    roads = _samples(frame, road_lon, road_lat, road_line, np.full(len(rx), "driving", dtype=object))

    # junction position: the mean of its connecting roads' end points (one vectorised evaluation)
    owner, road_rows, s_values = [], [], []
    for number, junction in enumerate(odr.junctions):
        for connection in junction.connections:
            row = odr.road_index.get(connection.connecting_road)
            if row is not None:
                owner += [number, number]
                road_rows += [row, row]
                s_values += [0.0, odr.roads[row].length]
    owner = np.array(owner, dtype=np.int64)
    jx_local, jy_local, *_ = odr.arrays.reference(np.array(road_rows, dtype=np.int64), np.array(s_values))
    counts = np.bincount(owner, minlength=len(odr.junctions))
    has_points = counts > 0
    junction_xy = np.column_stack([np.bincount(owner, jx_local, len(odr.junctions))[has_points],
                                   np.bincount(owner, jy_local, len(odr.junctions))[has_points]])
    junction_xy = junction_xy / counts[has_points, None]
    j_lon, j_lat = (np.asarray(v) for v in odr.georeference.local_to_wgs84(junction_xy[:, 0], junction_xy[:, 1]))
    jx, jy = frame.from_lonlat(j_lon, j_lat)

    graph = LaneGraph.from_opendrive(odr)
    scc = graph.largest_strongly_connected()
    share = sum(graph.length(k) for k in scc) / graph.total_length if graph.total_length else 0.0
    dead_ends = sum(1 for k in graph.keys if not graph.successors(k))
    network = Network(str(path), "opendrive", lanes, (lon, lat), roads, (road_lon, road_lat),
                      np.column_stack([jx, jy]), np.column_stack([j_lon, j_lat]), float(share), dead_ends)
    return network, frame


# ------------------------------------------------------------------ SUMO

def _sumo_lane_type(allow: str | None, disallow: str | None) -> str | None:
    """The OpenDRIVE lane type netconvert gives a SUMO lane with these permissions (None: not a road lane)."""
    allowed = set((allow or "").split())
    if allowed:
        if "passenger" in allowed:
            return "driving"
        if allowed <= {"pedestrian"}:
            return "sidewalk"
        if allowed <= {"bicycle"}:
            return "biking"
        if allowed <= {"rail", "rail_urban", "rail_electric", "rail_fast", "tram", "subway", "cable_car", "ship"}:
            return None
        return "restricted"
    denied = set((disallow or "").split())
    if "all" in denied:
        return None
    return "restricted" if "passenger" in denied else "driving"


def _shape(text: str | None) -> np.ndarray:
    points = [tuple(float(v) for v in point.split(",")[:2]) for point in (text or "").split()]
    return np.array(points, dtype=float).reshape(-1, 2)


def _checked_shape(lane, file: str) -> np.ndarray:
    """A lane's @shape as (n, 2) points; a shape that is not numbers, or not on Earth, is one line of error."""
    try:
        shape = _shape(lane.get("shape"))
    except ValueError:
        raise InputError(f"lane {lane.get('id')}: @shape is not a list of x,y numbers", file=file,
                         line=lane.sourceline, element="lane") from None
    bad = np.flatnonzero(off_earth(shape[:, 0], shape[:, 1]))
    if len(bad):
        x, y = shape[bad[0]]
        raise InputError(f"lane {lane.get('id')}: @shape vertex {vertex_problem(x, y) or f'x={x}, y={y}'}",
                         file=file, line=lane.sourceline, element="lane")
    return shape


def load_sumo_network(path: str, frame, step: float = 0.5) -> Network:
    """Lane shapes of a SUMO network (.net.xml[.gz]); net coordinates = projected + netOffset."""
    from tavf_mapkit.lanegraph.edges import strong_components
    from tavf_mapkit.sumonet import read_net_bytes
    from tavf_mapkit.xmlsafe import iterparse_safe, prepare_xml_bytes

    name = str(path)
    source = prepare_xml_bytes(read_net_bytes(path), name)
    location = None
    shapes, types, lane_ids, lane_edge, lane_index, internal = [], [], [], [], [], []
    junctions, connections = [], []
    edge_id, edge_function = None, None
    root_checked = False
    for event, element in iterparse_safe(source, events=("start", "end")):
        tag = element.tag
        if event == "start":
            if not root_checked:
                root_checked = True
                if tag != "net":
                    raise InputError(f"expected a SUMO network (<net>), found <{tag}>", file=name,
                                     line=element.sourceline)
            if tag == "edge":
                edge_id, edge_function = element.get("id"), element.get("function", "normal")
            continue
        if tag == "location":
            location = element.attrib
        elif tag == "lane" and edge_function in ("normal", "internal"):
            lane_type = _sumo_lane_type(element.get("allow"), element.get("disallow"))
            shape = _checked_shape(element, name)
            if lane_type is not None and len(shape) >= 2:
                shapes.append(shape)
                types.append(lane_type)
                lane_ids.append(element.get("id"))
                lane_edge.append(edge_id)
                lane_index.append(int(element.get("index", 0)))
                internal.append(edge_function == "internal")
        elif tag == "junction" and element.get("type") not in ("internal", "dead_end"):
            junctions.append((float(element.get("x", 0)), float(element.get("y", 0))))
        elif tag == "connection" and element.get("fromLane") is not None:
            connections.append((f"{element.get('from')}_{element.get('fromLane')}",
                                f"{element.get('to')}_{element.get('toLane')}"))
        if tag in ("edge", "junction", "connection", "tlLogic"):
            element.clear()
    if location is None:
        raise InputError("the SUMO network has no <location> element", file=name)
    proj = location.get("projParameter", "!")
    if not proj or proj == "!":
        raise InputError("the SUMO network is not georeferenced (projParameter '!')", file=name)
    try:
        offset = tuple(float(v) for v in location.get("netOffset", "0,0").split(","))
        crs = pyproj.CRS.from_user_input(proj)
    except (ValueError, pyproj.exceptions.CRSError) as error:
        raise InputError(f"bad <location>: {error}", file=name) from None
    if not shapes:
        raise InputError("the SUMO network has no lanes", file=name)
    to_wgs84 = pyproj.Transformer.from_crs(crs, _WGS84, always_xy=True)

    def lonlat(xy):
        return (np.asarray(v) for v in to_wgs84.transform(xy[:, 0] - offset[0], xy[:, 1] - offset[1]))

    counts = np.array([len(s) for s in shapes])
    vertex_line = np.repeat(np.arange(len(shapes)), counts)
    lane_points = np.array([np.linalg.norm(np.diff(s, axis=0), axis=1).sum() for s in shapes]) / step + 2
    if not lane_points.sum() <= MAX_POINTS:  # before allocating, as every sampler (opendrive/budget.py)
        worst = int(np.argmax(lane_points))
        raise InputError(f"sampling its lanes every {step:g} m would allocate {lane_points.sum():.3g} points, more "
                         f"than the budget of {MAX_POINTS:.3g} (lane {lane_ids[worst]} alone "
                         f"{lane_points[worst]:.3g})", file=name)
    points, line = resample_polylines(np.vstack(shapes), vertex_line, step)
    lon, lat = lonlat(points)
    lane_type = np.array(types, dtype=object)[line]
    lanes = _samples(frame, lon, lat, line, lane_type)

    # road centres: per normal edge, the middle of its outermost driving lanes (resampled by fraction)
    by_edge: dict[str, list[int]] = {}
    for i, (edge, kind, is_internal) in enumerate(zip(lane_edge, types, internal)):
        if kind == "driving" and not is_internal:
            by_edge.setdefault(edge, []).append(i)
    road_points, road_lines = [], []
    for number, members in enumerate(by_edge.values()):
        members = sorted(members, key=lambda i: lane_index[i])
        outer = [shapes[members[0]], shapes[members[-1]]]
        length = max(float(np.linalg.norm(np.diff(s, axis=0), axis=1).sum()) for s in outer)
        fractions = np.linspace(0.0, 1.0, max(int(np.ceil(length / step)), 1) + 1)
        resampled = [_at_fractions(s, fractions) for s in outer]
        road_points.append(0.5 * (resampled[0] + resampled[1]))
        road_lines.append(np.full(len(fractions), number))
    road_xy = np.vstack(road_points) if road_points else np.zeros((0, 2))
    road_line = np.concatenate(road_lines) if road_lines else np.zeros(0, dtype=np.int64)
    road_lon, road_lat = lonlat(road_xy)
    roads = _samples(frame, road_lon, road_lat, road_line, np.full(len(road_xy), "driving", dtype=object))

    junction_xy = np.array(junctions, dtype=float).reshape(-1, 2)
    j_lon, j_lat = lonlat(junction_xy)
    jx, jy = frame.from_lonlat(j_lon, j_lat)

    # connectivity of the driving lanes: connections plus changes between neighbouring lanes of an edge
    length = {lane_ids[i]: float(np.linalg.norm(np.diff(shapes[i], axis=0), axis=1).sum())
              for i in range(len(shapes)) if types[i] == "driving" and not internal[i]}
    ids = list(length)
    node = {k: i for i, k in enumerate(ids)}
    pairs = [(node[a], node[b]) for a, b in connections if a in node and b in node]
    for members in by_edge.values():
        ordered = [node[lane_ids[i]] for i in sorted(members, key=lambda i: lane_index[i])]
        for a, b in itertools.pairwise(ordered):
            pairs += [(a, b), (b, a)]
    source, target = (np.array(column, dtype=np.int64) for column in zip(*pairs)) if pairs else \
        (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64))
    count, label = strong_components(len(ids), source, target)
    lane_length = np.array([length[k] for k in ids])
    total = float(lane_length.sum())
    share = float(np.bincount(label, weights=lane_length, minlength=count).max()) / total if total else 0.0
    # a dead end: no way on into another SUMO edge (lane changes within the edge do not count)
    edge_of = np.array([k.rsplit("_", 1)[0] for k in ids], dtype=object)
    leaves = source[edge_of[source] != edge_of[target]]
    dead_ends = len(ids) - len(np.unique(leaves))
    return Network(name, "sumo", lanes, (lon, lat), roads, (road_lon, road_lat), np.column_stack([jx, jy]),
                   np.column_stack([j_lon, j_lat]), float(share), dead_ends)


def _at_fractions(shape: np.ndarray, fractions: np.ndarray) -> np.ndarray:
    arc = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(shape, axis=0), axis=1))]
    target = fractions * arc[-1]
    return np.column_stack([np.interp(target, arc, shape[:, 0]), np.interp(target, arc, shape[:, 1])])


def load_network(path: str | Path, frame, step: float = 0.5) -> Network:
    from tavf_mapkit.sumonet import is_sumo_net

    if is_sumo_net(path):
        return load_sumo_network(str(path), frame, step)
    network, _ = load_opendrive_network(str(path), frame, step)
    return network
