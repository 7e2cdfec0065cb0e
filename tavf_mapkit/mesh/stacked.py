"""Where a road-side surface of one road lies on a driving lane of another, a little higher: the driving lane
wins.

OpenDRIVE lets roads overlap. Where a lane that is not for driving (sidewalk, shoulder, border, ...) of one
road covers a driving lane of another road from a few centimetres up, a car on the driving lane runs into it:
its wheels climb the other road's surface as they would a curb. CARLA's Town07 draws the sidewalks at the
mouth of a side street as a road of their own (lanes sidewalk, shoulder, none), 12-15 cm above the through
road by their elevation, and lets it reach 2.6 m into the through road's driving lane; the twin's car hit that
edge four times in ten minutes. Such parts are cut out of the road-side faces: exact plan-view clipping of
each triangle by the driving triangles it stands on, the rest triangulated again (GEOS constrained Delaunay),
heights and (s, t) taken on the triangle's own plane, so what is left is the same surface, only smaller.

Left alone: overlaps at the same height (less than ``STACK_MIN`` up: the same ground drawn twice, nothing to
run into; CARLA's towns have hundreds), road-side surfaces below a driving lane (a car never meets them), and
anything ``STACK_CLEARANCE`` or more above it (bridges, whose decks are 4 m and more up).
"""

from __future__ import annotations

import numpy as np
import shapely

from tavf_mapkit.mesh.junctions import _barycentric, _overlay, _union
from tavf_mapkit.mesh.labelled import KIND_CODE, LabelledMesh

STACK_MIN = 0.05        # m: a road-side surface less than this above a driving lane is the same ground
STACK_CLEARANCE = 2.5   # m: one this high above it or more is a deck a car passes under
MIN_OVERLAP = 1e-4      # m^2: smaller plan overlaps are touching borders and rounding, not stacking
WELD = 1e-7             # m: new vertices this close (cut edges shared by neighbouring triangles) are one


def _plan_polygons(mesh: LabelledMesh, faces: np.ndarray) -> np.ndarray:
    corners = mesh.vertices[mesh.faces[faces]][:, :, :2]
    return shapely.polygons(np.concatenate([corners, corners[:, :1]], axis=1))


def _height_on(mesh: LabelledMesh, faces: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Height of each face's plane at a plan point (one point per face)."""
    corners = mesh.vertices[mesh.faces[faces]]
    weights = _barycentric(points, corners[:, :, :2])
    return np.einsum("ij,ij->i", weights, corners[:, :, 2])


def stacked_regions(mesh: LabelledMesh, candidates: np.ndarray, driving: LabelledMesh) -> dict[int, object]:
    """Face index (of ``candidates``, faces of ``mesh``) -> the plan region of it that lies on driving faces
    of other roads, from ``STACK_MIN`` to ``STACK_CLEARANCE`` above them."""
    if not len(candidates) or not len(driving.faces):
        return {}
    own = _plan_polygons(mesh, candidates)
    lanes = _plan_polygons(driving, np.arange(len(driving.faces)))
    pair_face, pair_lane = shapely.STRtree(lanes).query(own, predicate="intersects")
    other = mesh.road_index[candidates[pair_face]] != driving.road_index[pair_lane]
    pair_face, pair_lane = pair_face[other], pair_lane[other]
    if not len(pair_face):
        return {}
    # cheap height test on the corners first: the road-side face must reach above the lane's lowest corner
    face_z = mesh.vertices[mesh.faces[candidates[pair_face]]][:, :, 2]
    lane_z = driving.vertices[driving.faces[pair_lane]][:, :, 2]
    near = ((face_z.max(axis=1) > lane_z.min(axis=1) + STACK_MIN)
            & (face_z.min(axis=1) < lane_z.max(axis=1) + STACK_CLEARANCE))
    pair_face, pair_lane = pair_face[near], pair_lane[near]
    if not len(pair_face):
        return {}
    overlap = _overlay(shapely.intersection, own[pair_face], lanes[pair_lane])
    big = shapely.area(overlap) > MIN_OVERLAP
    pair_face, pair_lane, overlap = pair_face[big], pair_lane[big], overlap[big]
    if not len(pair_face):
        return {}
    # two triangles overlap in a convex region: its centroid lies on both
    centre = shapely.get_coordinates(shapely.centroid(overlap))
    rise = _height_on(mesh, candidates[pair_face], centre) - _height_on(driving, pair_lane, centre)
    stacked = (rise > STACK_MIN) & (rise < STACK_CLEARANCE)
    found: dict[int, list] = {}
    for face, region in zip(candidates[pair_face[stacked]].tolist(), overlap[stacked]):
        found.setdefault(face, []).append(region)
    return {face: _union(regions) for face, regions in found.items()}


def cut_stacked_roadside(mesh: LabelledMesh, driving: LabelledMesh) -> tuple[LabelledMesh, dict[int, object]]:
    """(``mesh`` with its road-side faces cut where they stand on driving faces of other roads, road index ->
    the plan region cut away from that road). ``driving``: the driving-lane faces of the roads around (those
    of ``mesh``'s own roads may be among them; a road is never cut by itself). Faces keep their order, each
    cut face replaced in place by the triangles of what is left of it; vertical curb faces of a road standing
    in its cut region are dropped."""
    kind = mesh.kind
    corners = mesh.vertices[mesh.faces][:, :, :2]
    u, v = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    plan_area = 0.5 * np.abs(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0])
    roadside = (kind != KIND_CODE["driving"]) & (kind != KIND_CODE["junction"]) & (kind != KIND_CODE["curb"])
    regions = stacked_regions(mesh, np.flatnonzero(roadside & (plan_area > MIN_OVERLAP)), driving)
    if not regions:
        return mesh, {}
    faces = np.array(sorted(regions))
    pieces = shapely.intersection(_plan_polygons(mesh, faces), np.array([regions[f] for f in faces.tolist()]))
    face_road = mesh.road_index[faces]
    cut = {int(road): _union(pieces[face_road == road]) for road in np.unique(face_road)}
    replaced = {face: _remaining_triangles(mesh, face, regions[face]) for face in faces.tolist()}
    standing = set()
    for road, region in cut.items():
        curb = np.flatnonzero((kind == KIND_CODE["curb"]) & (mesh.road_index == road))
        middle = corners[curb].mean(axis=1)
        standing.update(curb[shapely.contains_xy(region, middle[:, 0], middle[:, 1])].tolist())
    return _rebuilt(mesh, replaced, standing), cut


def _remaining_triangles(mesh: LabelledMesh, face: int, region) -> np.ndarray:
    """Plan triangles (k, 3, 2) of what is left of ``face`` without ``region``, oriented as the face."""
    polygon = _plan_polygons(mesh, np.array([face]))[0]
    rest = _overlay(shapely.difference, polygon, region)
    parts = shapely.get_parts(rest)
    parts = parts[(shapely.get_type_id(parts) == 3) & (shapely.area(parts) > 0)]
    if not len(parts):
        return np.zeros((0, 3, 2))
    triangles = shapely.get_parts(shapely.constrained_delaunay_triangles(parts))
    triangles = triangles[shapely.get_type_id(triangles) == 3]
    coords = shapely.get_coordinates(triangles).reshape(-1, 4, 2)[:, :3]
    a, b, c = coords[:, 0], coords[:, 1], coords[:, 2]
    signed = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    corners = mesh.vertices[mesh.faces[face]][:, :2]
    (ux, uy), (vx, vy) = corners[1] - corners[0], corners[2] - corners[0]
    own = ux * vy - uy * vx
    flip = np.sign(signed) != np.sign(own)
    coords[flip] = coords[flip][:, [0, 2, 1]]
    return coords[signed != 0]


def _rebuilt(mesh: LabelledMesh, replaced: dict[int, np.ndarray], dropped: set[int]) -> LabelledMesh:
    """The mesh with faces replaced by plan triangles on their own plane (new vertices welded per road, and to
    the face's own corners), and ``dropped`` faces left out; every other face and vertex as it was."""
    faces, source, new_vertices, new_uv = [], [], [], []
    welded: dict[tuple, int] = {}
    count = len(mesh.vertices)
    for face in range(len(mesh.faces)):
        if face in dropped:
            continue
        if face not in replaced:
            faces.append(mesh.faces[face][None, :])
            source.append(face)
            continue
        triangles = replaced[face]
        if not len(triangles):
            continue
        corners = mesh.vertices[mesh.faces[face]]
        points = triangles.reshape(-1, 2)
        weights = _barycentric(points, np.repeat(corners[None, :, :2], len(points), axis=0))
        z = weights @ corners[:, 2]
        uv = weights @ mesh.uv[mesh.faces[face]] if mesh.uv is not None else None
        road = int(mesh.road_index[face])
        index = np.empty(len(points), dtype=np.int64)
        for k, (x, y) in enumerate(points):
            key = (road, round(x / WELD), round(y / WELD))
            hit = welded.get(key)
            if hit is None:
                exact = np.flatnonzero(np.all(corners[:, :2] == (x, y), axis=1))
                if len(exact):
                    hit = int(mesh.faces[face][exact[0]])
                else:
                    hit = count
                    count += 1
                    new_vertices.append((x, y, z[k]))
                    new_uv.append(uv[k] if uv is not None else (0.0, 0.0))
                welded[key] = hit
            index[k] = hit
        faces.append(index.reshape(-1, 3))
        source.extend([face] * len(triangles))
    source = np.array(source, dtype=np.int64)
    vertices = np.concatenate([mesh.vertices, np.array(new_vertices).reshape(-1, 3)])
    uv = None if mesh.uv is None else np.concatenate([mesh.uv, np.array(new_uv).reshape(-1, 2)])
    face_array = np.concatenate(faces) if faces else np.zeros((0, 3), dtype=np.int64)
    return LabelledMesh(vertices, face_array.astype(np.int64), mesh.road_index[source], mesh.lane_id[source],
                        mesh.kind[source], uv)
