"""Agreement with independent lane-border evaluations (libOpenDRIVE) for six real OpenDRIVE files."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.peers.borders import border_agreement, read_borders
from tavf_mapkit.opendrive import load_opendrive
from tavf_mapkit.opendrive.geometry import GeometryKind
from tests.conftest import shared_path

REFERENCE_FILES = ["crest-curve", "curves_elevation", "e6mini", "fabriksgatan", "multi_intersections", "test"]


def _xodr(name: str):
    if name == "test":
        return shared_path("xodr", "libopendrive", "test.xodr")
    return shared_path("xodr", "esmini", f"{name}.xodr")


def _paramPoly3_length_mismatch(road) -> np.ndarray:
    """Per geometry |true arc length - @length| of paramPoly3 records (0 for other kinds)."""
    out = []
    for g in road.reference_line.geometries:
        if g.kind is not GeometryKind.PARAM_POLY3:
            out.append(0.0)
            continue
        a_u, b_u, c_u, d_u, a_v, b_v, c_v, d_v, normalized = g.params
        p_end = 1.0 if normalized else g.length
        p = np.linspace(0.0, p_end, 20001)
        speed = np.hypot(b_u + p * (2 * c_u + 3 * d_u * p), b_v + p * (2 * c_v + 3 * d_v * p))
        out.append(abs(np.trapezoid(speed, p) - g.length))
    return np.array(out)


@pytest.mark.parametrize("name", REFERENCE_FILES)
def test_lane_borders_agree_with_independent_implementation(name):
    odr = load_opendrive(_xodr(name))
    rows = read_borders(shared_path("reference", "lane_borders", f"{name}.csv.gz"))
    agreement = border_agreement(odr, rows, 0.5)
    # same sample set on both sides (Town07 has sections 0.4 µm apart, so a few keys coincide)
    assert len(agreement.ours.s) == len(rows) and agreement.matched.all()
    distance = agreement.distance

    # Where a paramPoly3's true arc length differs from its @length, the two implementations resolve the
    # file's own inconsistency differently (both read s as arc length, but libOpenDRIVE pins s = @length to the
    # curve's end and squeezes the mismatch into its last lookup segment; we leave the gap at the end, which
    # the validator reports); allow exactly that mismatch there.
    tolerance = np.full(len(rows), 1e-3)
    for road in odr.roads:
        mismatch = _paramPoly3_length_mismatch(road)
        if not mismatch.any():
            continue
        rows_of_road = rows["road"].astype(str) == road.id
        geometry = road.reference_line.geometry_index(rows["s"][rows_of_road])
        tolerance[rows_of_road] += mismatch[geometry]
    assert np.all(distance < tolerance), f"max {distance.max():.2e} m at row {int(np.argmax(distance - tolerance))}"
    # and the bulk of rows agree far better than a millimetre
    assert np.median(distance) < 1e-4


def test_paramPoly3_inconsistency_is_what_separates_us_from_the_reference():
    """The only rows of e6mini off by more than 1 mm lie on the geometry whose length is off by 1.6 mm."""
    odr = load_opendrive(_xodr("e6mini"))
    mismatch = _paramPoly3_length_mismatch(odr.roads[0])
    assert mismatch.max() == pytest.approx(1.62e-3, abs=5e-5)
