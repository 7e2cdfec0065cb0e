"""(s, t, h) -> (x, y, z): the road surface frame.

e_s is the 3D tangent of the reference line (slope from the elevation profile included); e_t is the horizontal
normal rotated about e_s by the superelevation angle; e_h = e_s x e_t. A point is P(s) + t*e_t + h*e_h.
"""

from __future__ import annotations

import numpy as np


def surface_frame(heading: np.ndarray, slope: np.ndarray, superelevation: np.ndarray):
    """Unit vectors (e_t, e_h) as (n, 3) arrays for the given heading, dz/ds and roll angle."""
    cos_h, sin_h = np.cos(heading), np.sin(heading)
    inv = 1.0 / np.sqrt(1.0 + slope * slope)
    cos_p, sin_p = inv, slope * inv
    cos_r, sin_r = np.cos(superelevation), np.sin(superelevation)
    # horizontal normal n = (-sin h, cos h, 0); binormal b = e_s x n = (-sin p cos h, -sin p sin h, cos p)
    e_t = np.column_stack([
        -cos_r * sin_h - sin_r * sin_p * cos_h,
        cos_r * cos_h - sin_r * sin_p * sin_h,
        sin_r * cos_p,
    ])
    e_s = np.column_stack([cos_p * cos_h, cos_p * sin_h, sin_p])
    e_h = np.cross(e_s, e_t)
    return e_t, e_h


def surface_points(x, y, z, heading, slope, superelevation, t, h=None) -> np.ndarray:
    """(n, 3) points P + t e_t (+ h e_h) for aligned arrays."""
    e_t, e_h = surface_frame(heading, slope, superelevation)
    points = np.column_stack([x, y, z]) + np.asarray(t, dtype=float)[:, None] * e_t
    if h is not None:
        points += np.asarray(h, dtype=float)[:, None] * e_h
    return points
