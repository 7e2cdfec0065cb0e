"""Solid: one watertight scene part (curb, object, signal, building) built with manifold3d, and the few
helpers every solid builder shares.

Solids are built around a local anchor (numbers near zero keep manifold3d's arithmetic exact) and moved to
OpenDRIVE local coordinates in float64 afterwards.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import manifold3d
import numpy as np

from tavf_mapkit.mesh.labelled import KIND_CODE, LabelledMesh


class SolidError(ValueError):
    """A part could not be made into a valid solid (the message says which and why)."""


@dataclass(frozen=True, eq=False)
class Solid:
    """A closed, oriented 2-manifold triangle mesh with its labels and where it came from."""

    kind: str          # curb, object, signal or building
    mesh: LabelledMesh
    source: str        # e.g. "road 12 object 3", "osm way 4711"

    @property
    def triangles(self) -> int:
        return len(self.mesh.faces)


def manifold_from_mesh(vertices: np.ndarray, faces: np.ndarray) -> manifold3d.Manifold:
    """A Manifold from a float64 triangle mesh; raises SolidError when it is not a closed oriented 2-manifold."""
    mesh = manifold3d.Mesh64(np.ascontiguousarray(vertices, dtype=np.float64),
                             np.ascontiguousarray(faces, dtype=np.uint64))
    solid = manifold3d.Manifold(mesh)
    check_manifold(solid, "mesh")
    return solid


def check_manifold(solid: manifold3d.Manifold, what: str) -> None:
    status = solid.status()
    if status != manifold3d.Error.NoError:
        raise SolidError(f"{what} is not a valid solid ({status.name})")
    if solid.is_empty():
        raise SolidError(f"{what} is empty")


def to_solid(solid: manifold3d.Manifold, kind: str, source: str, anchor=(0.0, 0.0, 0.0),
             road_index: int = -1, lane_id: int = 0) -> Solid:
    """Convert a checked Manifold (built around ``anchor``) into a labelled Solid in local coordinates."""
    check_manifold(solid, source)
    mesh = solid.to_mesh64()
    vertices = np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3] + np.asarray(anchor, dtype=np.float64)
    faces = np.asarray(mesh.tri_verts, dtype=np.int64)
    n = len(faces)
    labelled = LabelledMesh(vertices, faces, np.full(n, road_index, dtype=np.int32),
                            np.full(n, lane_id, dtype=np.int32), np.full(n, KIND_CODE[kind], dtype=np.int16))
    return Solid(kind, labelled, source)


def circle_segments(radius: float, eps: float) -> int:
    """Segments of a circle so that its polygon stays within ``eps`` of the true circle (8 to 64)."""
    if radius <= eps:
        return 8
    return int(min(64, max(8, math.ceil(math.pi / math.acos(1.0 - eps / radius)))))


def extrude_down(top_vertices: np.ndarray, top_faces: np.ndarray, depth) -> np.ndarray:
    """Close a height-field patch into a prism: the patch, a copy ``depth`` lower, and walls along its rim.

    ``top_faces`` must be counter-clockwise seen from above; ``depth`` is a scalar or one value per vertex.
    Returns (vertices, faces) of a closed mesh (validate it with :func:`manifold_from_mesh`).
    """
    n = len(top_vertices)
    depth = np.broadcast_to(np.asarray(depth, dtype=float), (n,))
    bottom = top_vertices - np.column_stack([np.zeros(n), np.zeros(n), depth])
    edges = np.concatenate([top_faces[:, [0, 1]], top_faces[:, [1, 2]], top_faces[:, [2, 0]]])
    # a rim edge is one whose reverse is not an edge of another face
    key = edges[:, 0] * n + edges[:, 1]
    reverse = edges[:, 1] * n + edges[:, 0]
    rim = edges[~np.isin(key, reverse)]
    a, b = rim[:, 0], rim[:, 1]
    walls = np.concatenate([np.column_stack([a, a + n, b + n]), np.column_stack([a, b + n, b])])
    faces = np.concatenate([top_faces, top_faces[:, ::-1] + n, walls])
    return np.concatenate([top_vertices, bottom]), faces


def strip_faces(columns: int, rows: int = 2) -> np.ndarray:
    """Faces of a grid of ``rows`` x ``columns`` vertices (row-major), counter-clockwise when rows go left
    of the direction in which columns advance."""
    index = np.arange(rows * columns).reshape(rows, columns)
    a, b = index[:-1, :-1].ravel(), index[:-1, 1:].ravel()
    c, d = index[1:, 1:].ravel(), index[1:, :-1].ravel()
    return np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])]).astype(np.int64)


def rotation_matrix(heading: float, pitch: float = 0.0, roll: float = 0.0) -> np.ndarray:
    """R = Rz(heading) Ry(pitch) Rx(roll): OpenDRIVE's heading-pitch-roll order."""
    ch, sh = math.cos(heading), math.sin(heading)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cr, sr = math.cos(roll), math.sin(roll)
    rz = np.array([[ch, -sh, 0.0], [sh, ch, 0.0], [0.0, 0.0, 1.0]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    return rz @ ry @ rx


def rotated(solid: manifold3d.Manifold, heading: float, pitch: float = 0.0, roll: float = 0.0):
    """The solid turned about the anchor by heading, pitch and roll (radians)."""
    r = rotation_matrix(heading, pitch, roll)
    return solid.transform(np.column_stack([r, np.zeros(3)]))
