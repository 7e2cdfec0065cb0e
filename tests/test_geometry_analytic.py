"""Analytic checks of every geometry type and every lateral record, independent of any other reader."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import fresnel

from tavf_mapkit.opendrive import loads_opendrive
from tests.xodr_factory import document, road_xml


def _road(geometry: str, length: float, **kwargs):
    return loads_opendrive(document(road_xml(geometry, length, **kwargs))).roads[0]


def test_line():
    road = _road('<geometry s="0" x="10" y="-5" hdg="0.5" length="100"><line/></geometry>', 100)
    x, y, hdg, k = road.reference_line.evaluate(np.array([0.0, 40.0, 100.0]))
    np.testing.assert_allclose(x, 10 + np.cos(0.5) * np.array([0, 40, 100]), atol=1e-12)
    np.testing.assert_allclose(y, -5 + np.sin(0.5) * np.array([0, 40, 100]), atol=1e-12)
    np.testing.assert_allclose(hdg, 0.5)
    np.testing.assert_allclose(k, 0.0)


@pytest.mark.parametrize("curvature", [0.02, -0.05, 1e-9, 0.3])
def test_arc_lies_on_its_circle(curvature):
    length = 2.0 / abs(curvature) if abs(curvature) > 1e-6 else 50.0
    road = _road(f'<geometry s="0" x="3" y="4" hdg="1.0" length="{length!r}"><arc curvature="{curvature!r}"/></geometry>',
                 length)
    s = np.linspace(0, length, 101)
    x, y, hdg, k = road.reference_line.evaluate(s)
    radius = 1.0 / curvature
    centre = np.array([3 - radius * np.sin(1.0), 4 + radius * np.cos(1.0)])
    np.testing.assert_allclose(np.hypot(x - centre[0], y - centre[1]), abs(radius), rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(hdg, 1.0 + curvature * s, atol=1e-12)
    # arc length between samples equals the chord-angle relation 2R sin(dθ/2)
    chord = np.hypot(np.diff(x), np.diff(y))
    np.testing.assert_allclose(chord, np.abs(2 * radius * np.sin(curvature * np.diff(s) / 2)), rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("c0,c1", [(0.0, 0.02), (0.01, -0.03), (-0.05, -0.01), (0.02, 0.02)])
def test_spiral_matches_fresnel_integrals(c0, c1):
    length = 80.0
    road = _road(f'<geometry s="0" x="0" y="0" hdg="0" length="{length}"><spiral curvStart="{c0}" curvEnd="{c1}"/>'
                 '</geometry>', length)
    s = np.linspace(0, length, 41)
    x, y, hdg, k = road.reference_line.evaluate(s)
    rate = (c1 - c0) / length
    np.testing.assert_allclose(k, c0 + rate * s, atol=1e-12)
    np.testing.assert_allclose(hdg, c0 * s + rate * s * s / 2, atol=1e-12)
    if rate == 0:
        return
    # Euler spiral through Fresnel integrals: shift to the point where curvature is zero
    u0 = c0 / rate
    scale = np.sqrt(np.pi / abs(rate))
    def canonical(u):
        S, C = fresnel(u / scale)
        return scale * C, np.sign(rate) * scale * S
    X0, Y0 = canonical(u0)
    X, Y = canonical(u0 + s)
    theta0 = rate * u0 * u0 / 2
    dx, dy = X - X0, Y - Y0
    expected_x = np.cos(-theta0) * dx - np.sin(-theta0) * dy
    expected_y = np.sin(-theta0) * dx + np.cos(-theta0) * dy
    np.testing.assert_allclose(x, expected_x, atol=1e-9)
    np.testing.assert_allclose(y, expected_y, atol=1e-9)


def test_poly3_arc_length_and_shape():
    # v = 0.01 u^2: a parabola; s must be its arc length
    c = 0.01
    u_end = 40.0
    length = float(u_end * np.sqrt(1 + (2 * c * u_end) ** 2) / 2 + np.arcsinh(2 * c * u_end) / (4 * c))
    road = _road(f'<geometry s="0" x="0" y="0" hdg="0" length="{length!r}"><poly3 a="0" b="0" c="{c}" d="0"/></geometry>',
                 length)
    x, y, hdg, k = road.reference_line.evaluate(np.array([length]))
    assert x[0] == pytest.approx(u_end, abs=1e-9)
    assert y[0] == pytest.approx(c * u_end ** 2, abs=1e-9)
    assert hdg[0] == pytest.approx(np.arctan(2 * c * u_end), abs=1e-12)
    assert k[0] == pytest.approx(2 * c / (1 + (2 * c * u_end) ** 2) ** 1.5, rel=1e-9)


@pytest.mark.parametrize("p_range", ["arcLength", "normalized"])
def test_param_poly3_is_arc_length_parametrised(p_range):
    # a cubic whose speed varies: u = 10 q + 5 q^2, v = 2 q^3 for q in [0, 1]
    q = np.linspace(0, 1, 200001)
    speed = np.hypot(10 + 10 * q, 6 * q * q)
    cumulative = np.concatenate([[0], np.cumsum((speed[1:] + speed[:-1]) / 2 * np.diff(q))])
    length = float(cumulative[-1])
    # arcLength: p runs over [0, @length], so the same curve has its coefficients rescaled
    P = 1.0 if p_range == "normalized" else length
    bu, cu, dv = 10.0 / P, 5.0 / P ** 2, 2.0 / P ** 3
    road = _road(f'<geometry s="0" x="1" y="2" hdg="0" length="{length!r}"><paramPoly3 aU="0" bU="{bu!r}" '
                 f'cU="{cu!r}" dU="0" aV="0" bV="0" cV="0" dV="{dv!r}" pRange="{p_range}"/></geometry>', length)
    s = np.linspace(0, length, 25)
    x, y, _, _ = road.reference_line.evaluate(s)
    q_at_s = np.interp(s, cumulative, q)
    np.testing.assert_allclose(x, 1 + 10 * q_at_s + 5 * q_at_s ** 2, atol=2e-6)
    np.testing.assert_allclose(y, 2 + 2 * q_at_s ** 3, atol=2e-6)
    # equal steps in s are equal distances along the curve
    steps = np.hypot(np.diff(x), np.diff(y))
    np.testing.assert_allclose(steps, length / 24, rtol=1e-3)


LANES_BORDER = """
<laneSection s="0">
  <left><lane id="2" type="sidewalk" level="false"><width sOffset="0" a="2" b="0" c="0" d="0"/></lane>
        <lane id="1" type="driving" level="false"><border sOffset="0" a="3" b="0.01" c="0" d="0"/></lane></left>
  <center><lane id="0" type="none" level="false"/></center>
  <right><lane id="-1" type="driving" level="false"><width sOffset="0" a="3" b="0" c="0" d="0"/>
          <border sOffset="0" a="-9" b="0" c="0" d="0"/></lane>
         <lane id="-2" type="shoulder" level="false"><width sOffset="0" a="1" b="0" c="0.001" d="0"/>
          <width sOffset="50" a="3.5" b="0" c="0" d="0"/></lane></right>
</laneSection>"""


def test_width_and_border_records_and_lane_offset():
    offset = '<laneOffset s="0" a="0.5" b="0" c="0" d="0"/><laneOffset s="60" a="0.5" b="0.01" c="0" d="0"/>'
    road = _road('<geometry s="0" x="0" y="0" hdg="0" length="100"><line/></geometry>', 100,
                 lanes=LANES_BORDER, lane_offset=offset)
    s = np.array([0.0, 30.0, 50.0, 70.0])
    t = road.lane_borders(0, s)
    lane_offset = np.where(s < 60, 0.5, 0.5 + 0.01 * (s - 60))
    np.testing.assert_allclose(t[0], lane_offset)
    # border record: absolute t from the reference line
    np.testing.assert_allclose(t[1], 3 + 0.01 * s)
    np.testing.assert_allclose(t[2], 3 + 0.01 * s + 2)
    # width wins over border when both are present (ASAM OpenDRIVE)
    np.testing.assert_allclose(t[-1], lane_offset - 3)
    # width records are cubic in ds from their own sOffset
    w2 = np.where(s < 50, 1 + 0.001 * s ** 2, 3.5)
    np.testing.assert_allclose(t[-2], lane_offset - 3 - w2)


def test_elevation_superelevation_surface_point():
    extra = ('<elevationProfile><elevation s="0" a="1" b="0.05" c="0" d="0"/></elevationProfile>'
             '<lateralProfile><superelevation s="0" a="0.1" b="0" c="0" d="0"/></lateralProfile>')
    road = _road('<geometry s="0" x="0" y="0" hdg="0" length="100"><line/></geometry>', 100, extra=extra)
    s = np.array([20.0])
    point = road.surface_point(s, 3.0)[0]
    pitch = np.arctan(0.05)
    # e_t = horizontal normal rotated about the 3D tangent by the roll angle
    e_t = np.array([-np.sin(0.1) * np.sin(pitch), np.cos(0.1), np.sin(0.1) * np.cos(pitch)])
    np.testing.assert_allclose(point, np.array([20.0, 0.0, 1 + 0.05 * 20]) + 3 * e_t, atol=1e-12)
    # without slope the documented shortcut holds: z = elevation + t sin(superelevation)
    flat = _road('<geometry s="0" x="0" y="0" hdg="0" length="100"><line/></geometry>', 100,
                 extra='<lateralProfile><superelevation s="0" a="0.2" b="0" c="0" d="0"/></lateralProfile>')
    assert flat.surface_point([5.0], -2.0)[0][2] == pytest.approx(-2.0 * np.sin(0.2), abs=1e-12)


def test_zero_length_geometry_and_section_are_tolerated():
    geometry = ('<geometry s="0" x="0" y="0" hdg="0" length="10"><line/></geometry>'
                '<geometry s="10" x="10" y="0" hdg="0" length="0"><arc curvature="0.1"/></geometry>'
                '<geometry s="10" x="10" y="0" hdg="0" length="10"><line/></geometry>')
    lanes = ('<laneSection s="0"><center><lane id="0" type="none"/></center><right><lane id="-1" type="driving">'
             '<width sOffset="0" a="3" b="0" c="0" d="0"/></lane></right></laneSection>'
             '<laneSection s="5"><center><lane id="0" type="none"/></center><right><lane id="-1" type="driving">'
             '<width sOffset="0" a="9" b="0" c="0" d="0"/></lane></right></laneSection>'
             '<laneSection s="5"><center><lane id="0" type="none"/></center><right><lane id="-1" type="driving">'
             '<width sOffset="0" a="3" b="0" c="0" d="0"/></lane></right></laneSection>')
    odr = loads_opendrive(document(road_xml(geometry, 20, lanes=lanes)))
    messages = [w.message for w in odr.warnings]
    assert any("zero-length <arc>" in m for m in messages)
    assert any("zero-length lane section" in m for m in messages)
    from tavf_mapkit.opendrive.sampling import sample_lane_borders

    borders = sample_lane_borders(odr, 1.0)
    assert np.all(np.isfinite(borders.x))
    assert np.allclose(borders.y, -3.0)  # the zero-length section with width 9 contributes nothing
