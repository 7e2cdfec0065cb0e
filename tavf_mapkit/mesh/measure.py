"""Distances from points to a triangle mesh: how far the mesh is from independent reference points."""

from __future__ import annotations

import numpy as np

from tavf_mapkit.mesh.planindex import PlanIndex


def closest_on_triangles(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Closest point on triangle (a, b, c) to p, row by row (Ericson, Real-Time Collision Detection 5.1.5)."""
    ab, ac, ap = b - a, c - a, p - a
    d1 = np.einsum("ij,ij->i", ab, ap)
    d2 = np.einsum("ij,ij->i", ac, ap)
    bp = p - b
    d3 = np.einsum("ij,ij->i", ab, bp)
    d4 = np.einsum("ij,ij->i", ac, bp)
    cp = p - c
    d5 = np.einsum("ij,ij->i", ab, cp)
    d6 = np.einsum("ij,ij->i", ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denominator = va + vb + vc
        v = vb / denominator
        w = vc / denominator
        out = a + ab * v[:, None] + ac * w[:, None]  # inside the face
        t_ab = d1 / (d1 - d3)
        t_ac = d2 / (d2 - d6)
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
    # the Voronoi regions, most specific last so that they win
    on_bc = (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0)
    out = np.where(on_bc[:, None], b + (c - b) * np.nan_to_num(t_bc)[:, None], out)
    on_ac = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
    out = np.where(on_ac[:, None], a + ac * np.nan_to_num(t_ac)[:, None], out)
    on_ab = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
    out = np.where(on_ab[:, None], a + ab * np.nan_to_num(t_ab)[:, None], out)
    out = np.where(((d6 >= 0) & (d5 <= d6))[:, None], c, out)
    out = np.where(((d3 >= 0) & (d4 <= d3))[:, None], b, out)
    out = np.where(((d1 <= 0) & (d2 <= 0))[:, None], a, out)
    # degenerate triangles: fall back to the nearest corner
    bad = ~np.all(np.isfinite(out), axis=1)
    if np.any(bad):
        corners = np.stack([a[bad], b[bad], c[bad]], axis=1)
        nearest = np.argmin(np.linalg.norm(corners - p[bad][:, None], axis=2), axis=1)
        out[bad] = corners[np.arange(len(nearest)), nearest]
    return out


def distance_to_mesh(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray,
                     search_radius: float = 0.5, chunk: int = 200_000) -> np.ndarray:
    """3D distance from each point to the nearest triangle whose plan-view box lies within
    ``search_radius`` (inf where there is none)."""
    tri = vertices[faces]
    point_index, face = PlanIndex(tri[:, :, :2], search_radius).candidates(points[:, :2])
    out = np.full(len(points), np.inf)
    for start in range(0, len(point_index), chunk):
        i, f = point_index[start:start + chunk], face[start:start + chunk]
        closest = closest_on_triangles(points[i], tri[f, 0], tri[f, 1], tri[f, 2])
        np.minimum.at(out, i, np.linalg.norm(points[i] - closest, axis=1))
    return out
