"""Fit a similarity transform (shift, rotation, scale) that moves one set of lines onto another.

Point-to-line ICP: each build sample is paired with the nearest reference sample of the same driving
direction and only its offset across the reference line counts (along a line nothing is observable).
Linearised least squares for (tx, ty, rotation, scale) about the build's centroid, iterated with a
shrinking pairing distance and Huber weights. A systematic georeference error shows up as a clear shift
or rotation with a small residual.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from tavf_mapkit.accuracy.polylines import LineSamples

DIRECTION_WEIGHT_M = 5.0  # metres a 90 deg heading difference costs when pairing samples


@dataclass(frozen=True)
class Similarity:
    """p_build = centre + scale * R(rotation) * (p_ref - centre) + (dx, dy): BUILD relative to REFERENCE."""

    dx: float
    dy: float
    rotation_deg: float
    scale: float
    centre: tuple[float, float]
    residual_rms_m: float
    pairs: int

    def to_dict(self) -> dict:
        return {"dx": round(self.dx, 4), "dy": round(self.dy, 4), "rotation_deg": round(self.rotation_deg, 5),
                "scale": round(self.scale, 7), "residual_rms_m": round(self.residual_rms_m, 4),
                "pairs": self.pairs}


def direction_tree(samples: LineSamples) -> cKDTree:
    w = DIRECTION_WEIGHT_M
    return cKDTree(np.column_stack([samples.x, samples.y, w * np.cos(samples.heading), w * np.sin(samples.heading)]))


def paired(tree: cKDTree, x, y, heading) -> np.ndarray:
    w = DIRECTION_WEIGHT_M
    _, index = tree.query(np.column_stack([x, y, w * np.cos(heading), w * np.sin(heading)]), k=1)
    return np.asarray(index)


def fit_similarity(build: LineSamples, reference: LineSamples, max_distance: float = 5.0,
                   iterations: int = 30, max_points: int = 20000, seed: int = 0) -> Similarity | None:
    if len(build) < 10 or len(reference) < 10:
        return None
    rng = np.random.default_rng(seed)
    keep = np.sort(rng.choice(len(build), size=min(max_points, len(build)), replace=False))
    x0, y0, heading0 = build.x[keep], build.y[keep], build.heading[keep]
    cx, cy = float(x0.mean()), float(y0.mean())
    tree = direction_tree(reference)
    scale, theta, tx, ty = 1.0, 0.0, 0.0, 0.0
    residual, count = math.nan, 0
    for iteration in range(iterations):
        c, s = math.cos(theta), math.sin(theta)
        px = cx + scale * (c * (x0 - cx) - s * (y0 - cy)) + tx
        py = cy + scale * (s * (x0 - cx) + c * (y0 - cy)) + ty
        index = paired(tree, px, py, heading0 + theta)
        bx, by, bh = reference.x[index], reference.y[index], reference.heading[index]
        nx, ny = -np.sin(bh), np.cos(bh)
        across = nx * (px - bx) + ny * (py - by)
        gap = np.hypot(px - bx, py - by)
        limit = max(max_distance * 0.5 ** max(iteration - 1, 0), 1.5)  # pair loosely first, then tighten
        use = (gap <= limit) & (np.cos(heading0 + theta - bh) > 0.7)
        if use.sum() < 10:
            return None
        rx, ry = px[use] - cx, py[use] - cy
        n_x, n_y, r = nx[use], ny[use], across[use]
        huber = np.minimum(1.0, 0.5 / np.maximum(np.abs(r), 1e-9))
        jacobian = np.column_stack([n_x, n_y, n_x * -ry + n_y * rx, n_x * rx + n_y * ry])
        weights = np.sqrt(huber)
        step, *_ = np.linalg.lstsq(jacobian * weights[:, None], -r * weights, rcond=None)
        dtx, dty, dtheta, dscale = step
        # compose the increment (about the centre) with the current transform
        c2, s2 = math.cos(dtheta), math.sin(dtheta)
        k = 1.0 + dscale
        tx, ty = k * (c2 * tx - s2 * ty) + dtx, k * (s2 * tx + c2 * ty) + dty
        scale, theta = scale * k, theta + dtheta
        residual, count = float(np.sqrt(np.mean(r ** 2))), int(use.sum())
        if iteration >= 8 and max(abs(dtx), abs(dty)) < 1e-5 and abs(dtheta) < 1e-8 and abs(dscale) < 1e-8:
            break
    # the fit maps build -> reference; BUILD relative to REFERENCE is its inverse, evaluated at the centre
    c, s = math.cos(-theta), math.sin(-theta)
    dx = -(c * tx - s * ty) / scale
    dy = -(s * tx + c * ty) / scale
    return Similarity(dx, dy, -math.degrees(theta), 1.0 / scale, (cx, cy), residual, count)
