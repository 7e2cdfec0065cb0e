"""Triangle hygiene: areas, normals, and dropping the degenerate triangles that zero-length geometries,
zero-width lanes and equal lane heights produce (never abort on them)."""

from __future__ import annotations

import numpy as np

from tavf_mapkit.mesh.labelled import LabelledMesh

MIN_AREA = 1e-8  # m^2


def face_cross(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(M, 3) cross product of each triangle's edges: normal direction times twice the area."""
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    return np.cross(b - a, c - a)


def triangle_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    return 0.5 * np.linalg.norm(face_cross(vertices, faces), axis=1)


def proper_faces(vertices: np.ndarray, faces: np.ndarray, min_area: float = MIN_AREA) -> np.ndarray:
    """Mask of triangles with three distinct corners and an area of at least ``min_area``."""
    f = faces
    keep = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])
    return keep & (triangle_areas(vertices, f) >= min_area)


def drop_degenerate(mesh: LabelledMesh, min_area: float = MIN_AREA) -> LabelledMesh:
    """The mesh without triangles of area below ``min_area`` or repeated corners, unused vertices dropped."""
    return mesh.select(proper_faces(mesh.vertices, mesh.faces, min_area))
