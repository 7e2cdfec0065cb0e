"""PlanIndex.covering (mesh/planindex.py) on a real map's road surface: the triangles each point lies in or near,
exactly as testing every point against every triangle's box and edge lines gives them."""

from __future__ import annotations

import numpy as np
import pytest

from tavf_mapkit.mesh.planindex import PlanIndex
from tavf_mapkit.mesh.surface import build_road_surface
from tavf_mapkit.opendrive import load_opendrive


def every_pair(index: PlanIndex, points: np.ndarray, tolerance: float) -> set:
    """(point, triangle) of every triangle whose grown box holds the point and whose edge lines it is within
    ``tolerance`` of, without the grid: the definition the grid only speeds up."""
    found = set()
    for start in range(0, len(points), 200):
        p = points[start:start + 200]
        px, py = p[:, None, 0, None], p[:, None, 1, None]  # (P, 1, 1)
        distance = index.normal_x[None] * px + index.normal_y[None] * py - index.offset[None]  # (P, T, 3)
        in_box = ((p[:, None, 0] >= index.box_low[None, :, 0] - tolerance)
                  & (p[:, None, 0] <= index.box_high[None, :, 0] + tolerance)
                  & (p[:, None, 1] >= index.box_low[None, :, 1] - tolerance)
                  & (p[:, None, 1] <= index.box_high[None, :, 1] + tolerance))
        point, triangle = np.nonzero(np.all(distance >= -tolerance, axis=2) & in_box)
        found |= set(zip((point + start).tolist(), triangle.tolist()))
    return found


@pytest.mark.parametrize("tolerance", [1e-3, 0.05])
def test_covering_is_every_triangle_near_each_point(shared, tolerance):
    odr = load_opendrive(shared("xodr", "esmini", "fabriksgatan.xodr"))
    mesh = build_road_surface(odr, 0.05).mesh
    plan = mesh.vertices[mesh.faces][:, :, :2]
    rng = np.random.default_rng(7)
    # points on vertices and edges (the hard cases) and scattered around them
    corners = plan.reshape(-1, 2)[rng.integers(0, 3 * len(plan), 1500)]
    middles = plan[rng.integers(0, len(plan), 1500)].mean(axis=1)
    points = np.concatenate([corners, middles, corners + rng.normal(0.0, 0.3, corners.shape)])
    index = PlanIndex(plan, 0.05)
    point, triangle = index.covering(points, tolerance)
    pairs = list(zip(point.tolist(), triangle.tolist()))
    assert len(pairs) == len(set(pairs)) and pairs == sorted(pairs, key=lambda pair: pair[0])
    assert set(pairs) == every_pair(index, points, tolerance)
    assert len(set(point.tolist())) > 3000  # most points are on the surface
