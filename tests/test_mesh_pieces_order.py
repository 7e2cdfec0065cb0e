"""The tiled mesher's shortcuts give exactly what they replace: swept paths found among nearby centre-line
pieces only, and key orders from one packed sort."""

from __future__ import annotations

import manifold3d
import numpy as np
import shapely

from tavf_mapkit.mesh.spill import key_order
from tavf_mapkit.mesh.swept_path import CentrePieces, centre_pieces, swept_areas, swept_section
from tavf_mapkit.opendrive import load_opendrive
from tests.conftest import shared_path


def test_key_order_is_lexsort_of_the_rows():
    rng = np.random.default_rng(7)
    for trial in range(2000):
        n, k = int(rng.integers(0, 40)), int(rng.integers(1, 5))
        high = (3, 1 << 20, 1 << 40, 1 << 62)[trial % 4]  # the last ones do not fit one int64 together
        keys = rng.integers(-2 if trial % 7 == 0 else 0, high, (n, k)).astype(np.int64)
        if trial % 3 == 0:  # two chunks, each in key order, as merge gets them
            keys = np.concatenate([keys[np.lexsort(keys.T[::-1])], keys])
        assert np.array_equal(key_order(keys), np.lexsort(keys.T[::-1]))


def _swept_section_of_every_line(lines, width, near, anchor):
    """swept_section as it was: an R-tree of every piece's LineString, queried within the widest reach."""
    _, hit = shapely.STRtree(lines).query(near, predicate="dwithin", distance=float(width.max()))
    hit = np.unique(hit)
    if not len(hit):
        return manifold3d.CrossSection()
    rings = shapely.get_exterior_ring(shapely.get_parts(swept_areas(lines[hit], width[hit])))
    coordinates, ring = shapely.get_coordinates(rings, return_index=True)
    cuts = np.flatnonzero(np.diff(ring)) + 1
    return manifold3d.CrossSection([part[:-1] - anchor for part in np.split(coordinates, cuts)],
                                   manifold3d.FillRule.Positive)


def test_swept_section_from_nearby_pieces_is_that_of_every_line():
    """Only the pieces whose plan box comes within reach get LineStrings; the swept section is, to the bit, the
    one made from every piece's LineString. The LineStrings made on demand are centre_pieces' ones."""
    odr = load_opendrive(shared_path("xodr", "esmini", "multi_intersections.xodr"))
    lines, width, road = centre_pieces(odr)
    pieces = CentrePieces.of(odr)
    assert len(lines) > 100
    assert np.array_equal(width, pieces.width) and np.array_equal(road, pieces.road)
    assert all(shapely.equals_exact(a, b, 0.0) for a, b in zip(lines, pieces.lines(np.arange(len(lines)))))
    rng = np.random.default_rng(3)
    found = 0
    for _ in range(25):
        centre = pieces.points[rng.integers(len(pieces.points))]  # near a lane, a few metres either way
        near = shapely.buffer(shapely.points(centre + rng.normal(0, 6, (3, 2))), 0.5 + rng.random(3) * 3)
        anchor = np.round(centre)
        ours = swept_section(odr, near, anchor, pieces=pieces).to_polygons()
        theirs = _swept_section_of_every_line(lines, width, near, anchor).to_polygons()
        assert len(ours) == len(theirs) and all(np.array_equal(a, b) for a, b in zip(ours, theirs))
        found += bool(len(ours))
    assert found >= 20  # most queries reach some lane


def test_pieces_reused_from_the_group_before_are_those_sampled_anew():
    """Junction-cluster groups take the pieces of the roads they share with the group before from it: the same
    arrays, in the same order, as sampling those roads again (a piece depends on its own lane alone)."""
    odr = load_opendrive(shared_path("xodr", "esmini", "multi_intersections.xodr"))
    rng = np.random.default_rng(5)
    n = len(odr.roads)
    for _ in range(8):
        before = rng.choice(n, int(rng.integers(1, n)), replace=False)
        now = np.concatenate([rng.choice(before, len(before) // 2, replace=False),
                              rng.choice(n, int(rng.integers(0, n // 2)), replace=False)])
        known = CentrePieces.of(odr, before)
        anew, reused = CentrePieces.of(odr, now), CentrePieces.of(odr, now, known)
        assert len(anew.width) > 0
        for name in ("points", "start", "width", "road", "low", "high", "made_for"):
            a, b = getattr(anew, name), getattr(reused, name)
            assert a.dtype == b.dtype and np.array_equal(a, b), name
