"""One clean surface per junction: the union of its connecting lanes' plan-view footprints, triangulated and
draped on the connecting lanes' elevation.

Connecting roads of a junction overlap each other by design, so meshing their lanes one by one gives
stacked triangles and z-fighting. Instead the footprints of the flat lanes (no lane height) are united with
shapely, small slits between neighbouring connecting roads closed, raised lanes (sidewalks with a height)
cut out -- they keep their own mesh and curbs. The union is cut on a grid of ``cell`` metres, so that no
triangle is larger than a cell, and each piece gets a constrained Delaunay triangulation (GEOS). Vertex
heights are the mean height of the connecting lane meshes at that point, so overlapping connecting roads are
averaged rather than fought over.

Labels of a junction face: kind "junction", road_index / lane_id / uv (s, t) of the connecting lane found
under the face centre (the first of several when they overlap).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely

from tavf_mapkit.mesh.labelled import KIND_CODE, LabelledMesh
from tavf_mapkit.mesh.planindex import PlanIndex

CLOSE_SLITS = 0.02   # m: gaps narrower than twice this between connecting lanes are closed
MIN_HOLE = 1.0       # m^2: smaller holes in the union are filled (numerical leftovers, not islands)
SNAP = 1e-9          # m: grid of the overlay fallback when GEOS's floating-point overlay fails
MIN_LANE_WEIGHT = 1e-3  # m: weight of a lane at its own border in a drape (never 0: a point it alone covers)


@dataclass(frozen=True, eq=False)
class JunctionSurfaces:
    mesh: LabelledMesh                      # every junction's surface, kind "junction"
    footprints: dict[str, object]           # junction id -> shapely (Multi)Polygon in local x, y


def lane_footprints(sampling, include: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(lane row per polygon, shapely polygons): plan-view footprint of every lane run of a sampling
    (only of lane rows where ``include`` is true, when given)."""
    lane = sampling.pair_lane
    if not len(lane):
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=object)
    cuts = np.flatnonzero(np.diff(lane)) + 1
    starts = np.concatenate([[0], cuts])
    counts = np.diff(np.concatenate([starts, [len(lane)]]))
    keep = counts >= 2
    if include is not None:
        keep &= include[lane[starts]]
    starts, counts = starts[keep], counts[keep]
    inner = sampling.points_at(sampling.t_inner)[:, :2]
    outer = sampling.points_at(sampling.t_outer)[:, :2]
    # ring per run: inner border forwards, outer border backwards
    run = np.repeat(np.arange(len(starts)), 2 * counts)
    k = np.arange(len(run)) - np.repeat(np.cumsum(2 * counts) - 2 * counts, 2 * counts)
    n = counts[run]
    forward = k < n
    index = np.where(forward, starts[run] + k, starts[run] + (2 * n - 1 - k))
    coords = np.where(forward[:, None], inner[index], outer[index])
    rings = shapely.linearrings(coords, indices=run)
    polygons = shapely.make_valid(shapely.polygons(rings))
    return lane[starts], polygons


def _union(geometries):
    """``shapely.union_all``, robust: where GEOS's floating-point overlay fails on nearly coincident edges
    (TopologyException: non-noded intersection), the union is made on a SNAP grid instead."""
    try:
        return shapely.union_all(geometries)
    except shapely.errors.GEOSException:
        return shapely.union_all(geometries, grid_size=SNAP)


def _overlay(operation, a, b):
    """A shapely overlay (difference, intersection) with the same fallback as ``_union``."""
    try:
        return operation(a, b)
    except shapely.errors.GEOSException:
        return operation(a, b, grid_size=SNAP)


def _polygonal(geometry):
    """The polygonal part of a geometry (make_valid and unions may add lines and points)."""
    parts = shapely.get_parts(geometry)
    parts = parts[np.isin(shapely.get_type_id(parts), (3, 6))]
    return _union(parts) if len(parts) else shapely.Polygon()


def _fill_small_holes(geometry, min_area: float):
    out = []
    for polygon in shapely.get_parts(geometry):
        holes = [ring for ring in polygon.interiors if shapely.Polygon(ring).area >= min_area]
        out.append(shapely.Polygon(polygon.exterior, holes))
    return _union(out) if out else shapely.Polygon()


def rows_by_name(names: np.ndarray):
    """(name, its row indices in ascending order) for each distinct name, names sorted: what a mask per name
    gives, by one stable sort (masks are names x rows: minutes for a city's 20,000 junctions)."""
    order = np.argsort(names, kind="stable")
    distinct, starts = np.unique(names[order], return_index=True)
    return zip(distinct.tolist(), np.split(order, starts[1:]))


def junction_footprints(odr, sampling, raised_rows: np.ndarray, uncovered=None,
                        junction_of_road: np.ndarray | None = None) -> dict[str, object]:
    """junction id -> united footprint of its flat connecting lanes, raised lanes cut out (except where they
    were cut away themselves, ``uncovered``: raised lanes standing on another road's driving lane,
    ``mesh.stacked``). ``junction_of_road``: each road's junction id, "" outside junctions
    (``MeshUnits.road_junction``; read from the roads when not given)."""
    arrays = odr.arrays
    if junction_of_road is None:
        junction_of_road = np.array([road.junction if road.in_junction else "" for road in odr.roads],
                                    dtype=object)
    rows, polygons = lane_footprints(sampling, junction_of_road[arrays.section_road[arrays.lane_section]] != "")
    if not len(rows):
        return {}
    junction = junction_of_road[arrays.section_road[arrays.lane_section[rows]]]
    raised = raised_rows[rows]
    out = {}
    for junction_id, mine in rows_by_name(junction):
        if junction_id == "":
            continue
        flat = _polygonal(_union(polygons[mine[~raised[mine]]]))
        if flat.is_empty:
            continue
        flat = flat.buffer(CLOSE_SLITS, join_style="mitre").buffer(-CLOSE_SLITS, join_style="mitre")
        if not flat.is_valid:  # GEOS's inward mitre buffer can cross itself at a needle-thin spike
            flat = shapely.make_valid(flat)
        if np.any(raised[mine]):
            standing = _polygonal(_union(polygons[mine[raised[mine]]]))
            if uncovered is not None and not uncovered.is_empty:
                standing = _polygonal(_overlay(shapely.difference, standing, uncovered))
            flat = _overlay(shapely.difference, flat, standing)
        flat = _fill_small_holes(_polygonal(flat), MIN_HOLE)
        if not flat.is_empty:
            out[junction_id] = flat
    return out


def triangulate_on_grid(footprint, cell: float, budget=None, road: int = 0) -> np.ndarray:
    """(M, 3, 2) counter-clockwise triangles covering the footprint, none larger than a grid cell.

    With a ``budget`` (the map's SampleBudget) the grid is checked against it first, charged to ``road``.
    """
    west, south, east, north = footprint.bounds
    x0, y0 = np.floor(west / cell) * cell, np.floor(south / cell) * cell
    nx, ny = max(1.0, np.ceil((east - x0) / cell)), max(1.0, np.ceil((north - y0) / cell))
    if budget is not None:
        budget.check_total(nx * ny, f"a junction surface grid of {cell:g} m cells", road)
    nx, ny = int(nx), int(ny)
    gx, gy = np.meshgrid(x0 + cell * np.arange(nx), y0 + cell * np.arange(ny))
    boxes = shapely.box(gx.ravel(), gy.ravel(), gx.ravel() + cell, gy.ravel() + cell)
    pieces = _overlay(shapely.intersection, footprint, boxes)
    pieces = shapely.get_parts(pieces[~shapely.is_empty(pieces)])
    pieces = pieces[shapely.get_type_id(pieces) == 3]
    if not len(pieces):
        return np.zeros((0, 3, 2))
    triangles = shapely.get_parts(shapely.constrained_delaunay_triangles(pieces))
    triangles = triangles[shapely.get_type_id(triangles) == 3]
    coords = shapely.get_coordinates(triangles).reshape(-1, 4, 2)[:, :3]
    a, b, c = coords[:, 0], coords[:, 1], coords[:, 2]
    signed = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    coords[signed < 0] = coords[signed < 0][:, [0, 2, 1]]
    return coords[np.abs(signed) > 0]


class Drape:
    """Heights and labels of a set of (connecting lane) triangles at plan-view points; built once, asked often.

    With ``groups`` (one number per triangle) a point only sees the triangles of its own group (its junction
    cluster), so what a cluster's surface becomes never depends on which other clusters are meshed with it."""

    def __init__(self, lanes: LabelledMesh, reach: float = 1e-3, groups: np.ndarray | None = None):
        self.lanes = lanes
        self.triangles = lanes.vertices[lanes.faces]  # (F, 3, 3)
        self.groups = np.zeros(len(lanes.faces), dtype=np.int64) if groups is None else np.asarray(groups)
        self.index = PlanIndex(self.triangles[:, :, :2], reach) if len(lanes.faces) else None
        self.outer, self.width = _lane_sides(lanes)

    def __call__(self, points: np.ndarray, distance: float = 1e-3, groups: np.ndarray | None = None):
        """Height (mean over the triangles within ``distance``), first such face, its (s, t), and the spread
        (max - min) of their heights. Where connecting roads disagree in height (CARLA's Town07 has junctions
        with 0.6 m between overlapping connecting lanes) no single surface can be within eps of all of them;
        the spread says by how much the data contradicts itself there. A point near no triangle takes the
        triangle with the nearest centre. ``groups``: each point's group (all 0 when not given)."""
        lanes, tri = self.lanes, self.triangles
        points = np.asarray(points, dtype=float)
        if self.index is None:
            zero = np.zeros(len(points))
            return zero, np.full(len(points), -1), np.zeros((len(points), 2)), zero
        groups = np.zeros(len(points), dtype=np.int64) if groups is None else np.asarray(groups)
        if distance > self.index.pad:
            self.index = PlanIndex(self.triangles[:, :, :2], distance)
        point_index, face = self.index.covering(points, distance)
        same = self.groups[face] == groups[point_index]
        point_index, face = point_index[same], face[same]
        missing = np.flatnonzero(np.bincount(point_index, minlength=len(points)) == 0)  # no face covers them
        if len(missing):
            nearest = _nearest_triangle(tri[:, :, :2], points[missing], self.groups, groups[missing])
            found = nearest >= 0
            point_index = np.concatenate([point_index, missing[found]])
            face = np.concatenate([face, nearest[found]])
        weights = _barycentric(points[point_index], tri[face, :, :2])
        z = np.einsum("ij,ij->i", weights, tri[face, :, 2])
        count = np.bincount(point_index, minlength=len(points))
        # each lane counts by how far inside it the point lies (its distance to the lane's nearer side
        # border), so where overlapping connecting lanes disagree in height the mean fades from one to the
        # other across a lane's width instead of stepping at the edge of its footprint (Town07's junction 763:
        # 9 cm steps a car's wheel took for a curb)
        if self.outer is None:
            lane_weight = np.ones(len(face))
        else:
            across = np.einsum("ij,ij->i", weights, self.outer[face])
            lane_weight = np.maximum(np.minimum(across, 1.0 - across) * self.width[face], MIN_LANE_WEIGHT)
        height = (np.bincount(point_index, weights=lane_weight * z, minlength=len(points))
                  / np.maximum(np.bincount(point_index, weights=lane_weight, minlength=len(points)), 1e-300))
        height[count == 0] = 0.0
        high = np.full(len(points), -np.inf)
        low = np.full(len(points), np.inf)
        np.maximum.at(high, point_index, z)
        np.minimum.at(low, point_index, z)
        spread = np.where(count > 0, high - low, 0.0)
        # the first hit per point carries the labels
        order = np.lexsort((face, point_index))
        point_index, face, weights = point_index[order], face[order], weights[order]
        first = np.ones(len(point_index), dtype=bool)
        first[1:] = point_index[1:] != point_index[:-1]
        label_face = np.full(len(points), -1)
        label_face[point_index[first]] = face[first]
        uv = np.zeros((len(points), 2))
        if lanes.uv is not None:
            uv_tri = lanes.uv[lanes.faces[face[first]]]
            uv[point_index[first]] = np.einsum("ij,ijk->ik", weights[first], uv_tri)
        return height, label_face, uv, spread


def _lane_sides(lanes: LabelledMesh) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Per face corner: 1.0 on the lane's outer border, 0.0 on its inner one; per face: the lane's width.
    Lane faces span a lane from border to border, so their corners' t (uv) take two values, the outer one
    farther from the centre on the lane's side. None for meshes without (s, t)."""
    if lanes.uv is None or not len(lanes.faces):
        return None, None
    t = lanes.uv[lanes.faces][:, :, 1]
    low, high = t.min(axis=1), t.max(axis=1)
    middle = 0.5 * (low + high)[:, None]
    outer = np.where((lanes.lane_id < 0)[:, None], t < middle, t > middle).astype(float)
    return outer, high - low


def _nearest_triangle(plan: np.ndarray, points: np.ndarray, triangle_groups: np.ndarray,
                      point_groups: np.ndarray) -> np.ndarray:
    """Index of the triangle of the point's own group whose centre is nearest to each point, -1 where the group
    has none (points off the lanes are rare and close to them). Exact, so it depends on the group alone."""
    from scipy.spatial import cKDTree

    centres = plan.mean(axis=1)
    best = np.full(len(points), -1)
    order = np.argsort(triangle_groups, kind="stable")
    sorted_groups = triangle_groups[order]
    for group in np.unique(point_groups):
        lo = np.searchsorted(sorted_groups, group, side="left")
        hi = np.searchsorted(sorted_groups, group, side="right")
        if hi <= lo:
            continue
        members = order[lo:hi]
        mine = np.flatnonzero(point_groups == group)
        _, nearest = cKDTree(centres[members]).query(points[mine])
        best[mine] = members[nearest]
    return best


def drape(points: np.ndarray, lanes: LabelledMesh, distance: float = 1e-3):
    """``Drape(lanes)(points, distance)`` for a single question."""
    return Drape(lanes, distance)(points, distance)


def _barycentric(p: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Barycentric weights of plan points in plan triangles, clamped to the triangle (points on or near it)."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    v0, v1, v2 = b - a, c - a, p - a
    d00 = np.einsum("ij,ij->i", v0, v0)
    d01 = np.einsum("ij,ij->i", v0, v1)
    d11 = np.einsum("ij,ij->i", v1, v1)
    d20 = np.einsum("ij,ij->i", v2, v0)
    d21 = np.einsum("ij,ij->i", v2, v1)
    denominator = d00 * d11 - d01 * d01
    safe = np.where(np.abs(denominator) > 1e-18, denominator, 1.0)
    v = np.where(np.abs(denominator) > 1e-18, (d11 * d20 - d01 * d21) / safe, 1 / 3)
    w = np.where(np.abs(denominator) > 1e-18, (d00 * d21 - d01 * d20) / safe, 1 / 3)
    weights = np.clip(np.column_stack([1.0 - v - w, v, w]), 0.0, None)
    return weights / weights.sum(axis=1, keepdims=True)


def _refine(plan: np.ndarray, faces: np.ndarray, height: np.ndarray, lanes: LabelledMesh, eps: float,
            min_edge: float, levels: int = 6, plan_group: np.ndarray | None = None,
            lane_group: np.ndarray | None = None, plan_road: np.ndarray | None = None,
            lane_drape: Drape | None = None):
    """Split junction triangles until their plane is within eps of the draped height at every edge midpoint
    and centre (or edges reach ``min_edge``). Edges are split at their midpoint for both neighbours, and each
    triangle is cut into 2, 3 or 4 by the pattern of its split edges, so the mesh stays conforming.
    ``plan_group`` / ``lane_group``: the cluster of every plan vertex and lane face (clusters never mix);
    ``plan_road``: the junction's first road of every plan vertex (carried along to new vertices);
    ``lane_drape``: ``Drape(lanes, groups=lane_group)`` made before (its index is the costly part)."""
    plan_group = np.zeros(len(plan), dtype=np.int64) if plan_group is None else plan_group
    plan_road = np.zeros(len(plan), dtype=np.int64) if plan_road is None else plan_road
    lane_group = np.zeros(len(lanes.faces), dtype=np.int64) if lane_group is None else lane_group
    # the connecting lanes' own vertices are check points too: they carry every feature of the height field
    # at the resolution the lanes were meshed with (cross slopes of neighbouring connecting roads, crests)
    lane_drape = Drape(lanes, groups=lane_group) if lane_drape is None else lane_drape
    vertex_group = np.zeros(len(lanes.vertices), dtype=np.int64)
    vertex_group[lanes.faces.ravel()] = np.repeat(lane_group, 3)
    keyed = np.unique(np.column_stack([vertex_group, np.round(lanes.vertices[:, :2], 6)]), axis=0)
    target_group, targets = keyed[:, 0].astype(np.int64), keyed[:, 1:]
    target_z = lane_drape(targets, groups=target_group)[0]
    for _ in range(levels):
        current = LabelledMesh(np.column_stack([plan, height]), faces, np.zeros(len(faces), dtype=np.int32),
                               np.zeros(len(faces), dtype=np.int32), np.zeros(len(faces), dtype=np.int16))
        face_group = plan_group[faces[:, 0]]
        mesh_z, under, _, _ = Drape(current, groups=face_group)(targets, groups=target_group)
        target_miss = under[(np.abs(mesh_z - target_z) > eps) & (under >= 0)]
        edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
        # distinct edges as one int64 each (first * n + second, second < n): sorted as the rows would be, and
        # without np.unique(axis=0)'s row-by-row sort
        code, edge_of = np.unique(edges[:, 0] * len(plan) + edges[:, 1], return_inverse=True)
        unique = np.column_stack([code // len(plan), code % len(plan)])
        edge_of = edge_of.reshape(-1, 3)  # face edge k runs from corner k to corner k+1
        mid = 0.5 * (plan[unique[:, 0]] + plan[unique[:, 1]])
        centre = plan[faces].mean(axis=1)
        z = lane_drape(np.concatenate([mid, centre]),
                       groups=np.concatenate([plan_group[unique[:, 0]], face_group]))[0]
        long_enough = np.linalg.norm(plan[unique[:, 0]] - plan[unique[:, 1]], axis=1) > min_edge
        split = long_enough & (np.abs(z[:len(mid)] - 0.5 * (height[unique[:, 0]] + height[unique[:, 1]])) > eps)
        # a centre that misses splits the triangle's longest edge
        centre_miss = np.abs(z[len(mid):] - height[faces].mean(axis=1)) > eps
        centre_miss[target_miss] = True
        corner = plan[faces]
        lengths = np.linalg.norm(corner - np.roll(corner, -1, axis=1), axis=2)
        longest = edge_of[np.arange(len(faces)), np.argmax(lengths, axis=1)]
        split[longest[centre_miss & long_enough[longest]]] = True
        if not split.any():
            break
        new_index = np.full(len(unique), -1)
        new_index[split] = len(plan) + np.arange(np.count_nonzero(split))
        plan = np.concatenate([plan, mid[split]])
        plan_group = np.concatenate([plan_group, plan_group[unique[split, 0]]])
        plan_road = np.concatenate([plan_road, plan_road[unique[split, 0]]])
        height = np.concatenate([height, z[:len(mid)][split]])
        faces = _split_faces(faces, new_index[edge_of])
    return plan, faces, height, plan_group, plan_road


def _split_faces(faces: np.ndarray, mids: np.ndarray) -> np.ndarray:
    """Cut each face by the midpoints of its split edges (mids[:, k] >= 0: edge k -> k+1 is split)."""
    marked = mids >= 0
    count = marked.sum(axis=1)
    out = [faces[count == 0]]
    # rotate every face so that its pattern is canonical: one split -> edge 0; two -> edges 0 and 1
    roll = np.zeros(len(faces), dtype=np.int64)
    one = count == 1
    roll[one] = np.argmax(marked[one], axis=1)
    two = count == 2
    roll[two] = (np.argmin(marked[two], axis=1) + 1) % 3  # the unsplit edge becomes edge 2
    k = (np.arange(3)[None, :] + roll[:, None]) % 3
    v = np.take_along_axis(faces, k, axis=1)
    m = np.take_along_axis(mids, k, axis=1)
    v0, v1, v2, m0, m1, m2 = v[:, 0], v[:, 1], v[:, 2], m[:, 0], m[:, 1], m[:, 2]
    out.append(np.column_stack([v0, m0, v2])[one])
    out.append(np.column_stack([m0, v1, v2])[one])
    out.append(np.column_stack([m0, v1, m1])[two])
    out.append(np.column_stack([v0, m0, m1])[two])
    out.append(np.column_stack([v0, m1, v2])[two])
    three = count == 3
    for triangle in ((v0, m0, m2), (m0, v1, m1), (m2, m1, v2), (m0, m1, m2)):
        out.append(np.column_stack(triangle)[three])
    return np.concatenate(out)


def junction_surfaces(odr, sampling, lanes: LabelledMesh, raised_rows: np.ndarray, cell: float = 5.0,
                      eps: float = 0.05, min_edge: float = 0.25,
                      group_of_road: np.ndarray | None = None, uncovered=None, units=None) -> JunctionSurfaces:
    """Surfaces of every junction. ``lanes`` are the connecting lanes' flat faces (for heights and labels);
    ``group_of_road``: the junction cluster (``mesh.units``) of every road -- a cluster's surfaces are draped on
    its own connecting lanes only (one cluster for the whole map when not given). ``units``: the map's
    ``MeshUnits``, for the roads' junctions found once (read from the roads when not given)."""
    footprints = junction_footprints(odr, sampling, raised_rows, uncovered,
                                     None if units is None else units.road_junction)
    plans, face_sets, groups, roads, offset = [], [], [], [], 0
    if units is not None:
        first_road = units.junction_first_road
    else:
        first_road = {}
        for index, road in enumerate(odr.roads):
            first_road.setdefault(road.junction, index)
    for junction_id, footprint in footprints.items():
        road = first_road.get(junction_id, 0)
        triangles = triangulate_on_grid(footprint, cell, odr.arrays.budget, road)
        if not len(triangles):
            continue
        flat = triangles.reshape(-1, 2)
        # pieces of the grid were triangulated one by one: shared corners are equal to rounding, weld them
        keys = np.round(flat / 1e-7).astype(np.int64)
        _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
        plans.append(flat[first])
        face_sets.append(inverse.reshape(-1, 3).astype(np.int64) + offset)
        groups.append(np.full(len(first), 0 if group_of_road is None else int(group_of_road[road]), dtype=np.int64))
        roads.append(np.full(len(first), road, dtype=np.int64))
        offset += len(first)
    if not plans or not len(lanes.faces):
        return JunctionSurfaces(LabelledMesh.empty(), footprints)
    plan = np.concatenate(plans)
    faces = np.concatenate(face_sets)
    plan_group = np.concatenate(groups)
    lane_group = (np.zeros(len(lanes.faces), dtype=np.int64) if group_of_road is None
                  else np.asarray(group_of_road, dtype=np.int64)[lanes.road_index])
    lane_drape = Drape(lanes, groups=lane_group)
    height = lane_drape(plan, groups=plan_group)[0]
    plan_road = np.concatenate(roads)
    plan, faces, height, plan_group, plan_road = _refine(plan, faces, height, lanes, eps, min_edge,
                                                         plan_group=plan_group, lane_group=lane_group,
                                                         plan_road=plan_road, lane_drape=lane_drape)
    # one query for vertices (s/t) and face centres (labels)
    _, label_face, uv, _ = lane_drape(np.concatenate([plan, plan[faces].mean(axis=1)]),
                                      groups=np.concatenate([plan_group, plan_group[faces[:, 0]]]))
    n = len(plan)
    uv, label_face = uv[:n], label_face[n:]
    # a face with no lane of its cluster under or near it (every flat lane degenerate) keeps its junction's
    # first road and no lane
    found = label_face >= 0
    road_index = np.where(found, lanes.road_index[label_face], plan_road[faces[:, 0]]).astype(np.int32)
    lane_id = np.where(found, lanes.lane_id[label_face], 0).astype(np.int32)
    return JunctionSurfaces(LabelledMesh(
        np.column_stack([plan, height]), faces, road_index, lane_id,
        np.full(len(faces), KIND_CODE["junction"], dtype=np.int16), uv), footprints)
