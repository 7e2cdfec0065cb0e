"""Curbs and raised sidewalks as solids: every raised lane (a lane ``height`` record above 0) of the road
surface, closed downwards into a prism that reaches CURB_FOUNDATION below the road level.

The solids are made from the road-surface mesh itself (its top faces are the surface's faces, vertex for
vertex), so they agree with the surface to the last bit and honour the same ``eps``. Lanes are found through
the surface's labels and (s, t) texture coordinates; a surface without (s, t) gets no curb solids.
"""

from __future__ import annotations

import numpy as np

from tavf_mapkit.mesh.labelled import KIND_CODE, LabelledMesh
from tavf_mapkit.mesh.solid_kit import Solid, SolidError, extrude_down, manifold_from_mesh, to_solid

CURB_FOUNDATION = 0.2   # m below the road level
MIN_RAISE = 1e-4        # m: lower lane heights are not a curb


def curb_solids(odr, surface: LabelledMesh) -> tuple[list[Solid], list[str]]:
    """One solid per connected raised part of a lane (road, lane section, lane)."""
    if surface is None or surface.uv is None or not len(surface.faces):
        return [], []
    raise_at_face, section = _face_heights(odr, surface)
    normal_z = _normal_z(surface)
    top = (raise_at_face > MIN_RAISE) & (normal_z > 0.3) & (surface.kind != KIND_CODE["curb"])
    if not np.any(top):
        return [], []
    solids, skipped = [], []
    keys = np.column_stack([surface.road_index, section, surface.lane_id])[top]
    faces_all = np.flatnonzero(top)
    groups, inverse = np.unique(keys, axis=0, return_inverse=True)
    for g, (road_index, section_index, lane_id) in enumerate(groups):
        group_faces = faces_all[inverse.ravel() == g]
        road = odr.roads[int(road_index)]
        for k, component in enumerate(_components(surface.faces[group_faces])):
            faces = group_faces[component]
            where = f"road {road.id} section {int(section_index)} lane {int(lane_id)} curb {k}"
            try:
                solids.append(_prism(surface, faces, float(raise_at_face[faces].max()), int(road_index),
                                     int(lane_id), where))
            except SolidError as error:
                skipped.append(f"{where}: {error}")
    return solids, skipped


def _normal_z(mesh: LabelledMesh) -> np.ndarray:
    v = mesh.vertices
    f = mesh.faces
    cross = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    length = np.linalg.norm(cross, axis=1)
    return np.divide(cross[:, 2], length, out=np.zeros(len(f)), where=length > 0)


def _face_heights(odr, surface: LabelledMesh):
    """Per face: the lane height (larger of inner/outer) at the face's mean s, and the lane section index."""
    arrays = odr.arrays
    n = len(surface.faces)
    height = np.zeros(n)
    section_of_face = np.full(n, -1, dtype=np.int64)
    on_lane = (surface.road_index >= 0) & (surface.lane_id != 0)
    if not np.any(on_lane) or not len(arrays.lane_id):
        return height, section_of_face
    idx = np.flatnonzero(on_lane)
    road = surface.road_index[idx].astype(np.int64)
    s = surface.uv[surface.faces[idx], 0].mean(axis=1)
    section_keys = arrays.section_road + arrays.section_s0 / arrays.span
    section = np.clip(np.searchsorted(section_keys, road + s / arrays.span, side="right") - 1, 0,
                      len(arrays.section_s0) - 1)
    section = np.where(arrays.section_road[section] == road, section, -1)
    # lane row of (section, lane id): lanes are stored section by section
    lane_keys = arrays.lane_section * 100000 + (arrays.lane_id + 50000)
    order = np.argsort(lane_keys, kind="stable")
    wanted = section * 100000 + (surface.lane_id[idx].astype(np.int64) + 50000)
    at = np.clip(np.searchsorted(lane_keys[order], wanted), 0, len(order) - 1)
    row = order[at]
    found = (section >= 0) & (lane_keys[row] == wanted)
    values = np.maximum(arrays.lane_height_inner.evaluate(row, s), arrays.lane_height_outer.evaluate(row, s))
    height[idx] = np.where(found, values, 0.0)
    section_of_face[idx] = section
    return height, section_of_face


def _components(faces: np.ndarray) -> list[np.ndarray]:
    """Face indices of each edge-connected component of a face set."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    m = len(faces)
    edges = np.concatenate([np.sort(faces[:, [0, 1]], axis=1), np.sort(faces[:, [1, 2]], axis=1),
                            np.sort(faces[:, [2, 0]], axis=1)])
    owner = np.tile(np.arange(m), 3)
    _, edge_id = np.unique(edges, axis=0, return_inverse=True)
    edge_id = edge_id.ravel()
    order = np.argsort(edge_id, kind="stable")
    same = edge_id[order][1:] == edge_id[order][:-1]
    a, b = owner[order][:-1][same], owner[order][1:][same]
    graph = coo_matrix((np.ones(len(a)), (a, b)), shape=(m, m))
    count, label = connected_components(graph, directed=False)
    return [np.flatnonzero(label == c) for c in range(count)]


def _prism(surface: LabelledMesh, faces: np.ndarray, max_raise: float, road_index: int, lane_id: int,
           where: str) -> Solid:
    used, local = np.unique(surface.faces[faces], return_inverse=True)
    top = surface.vertices[used]
    anchor = top.mean(axis=0)
    vertices, closed = extrude_down(top - anchor, local.reshape(-1, 3).astype(np.int64),
                                    max_raise + CURB_FOUNDATION)
    solid = manifold_from_mesh(vertices, closed)
    return to_solid(solid, "curb", where, anchor, road_index=road_index, lane_id=lane_id)
