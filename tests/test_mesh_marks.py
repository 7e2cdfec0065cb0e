"""Road marks: types, lengths, widths, colours, botts dots, lift above the surface."""

from __future__ import annotations

import numpy as np
import pytest

from tavf_mapkit.mesh import KIND_CODE, MARK_COLOURS, road_marks
from tavf_mapkit.mesh.cleanup import face_cross, triangle_areas
from tavf_mapkit.mesh.marks import BROKEN, DOT_HEIGHT, DOT_SIZE, LIFT
from tavf_mapkit.opendrive import loads_opendrive
from tests.xodr_factory import document, road_xml

STRAIGHT = '<geometry s="0" x="0" y="0" hdg="0" length="30"><line/></geometry>'


def _marks(mark_xml: str, centre_mark: str = "", geometry: str = STRAIGHT, length: float = 30.0, extra=""):
    lanes = f"""
        <laneSection s="0">
          <center><lane id="0" type="none" level="false">{centre_mark}</lane></center>
          <right><lane id="-1" type="driving" level="false"><width sOffset="0" a="3" b="0" c="0" d="0"/>
            {mark_xml}</lane></right>
        </laneSection>"""
    odr = loads_opendrive(document(road_xml(geometry, length, lanes=lanes, extra=extra)))
    return odr, road_marks(odr, 0.05)


def _area(mesh):
    return triangle_areas(mesh.vertices, mesh.faces).sum()


def test_solid_line_on_the_outer_border():
    _odr, marks = _marks('<roadMark sOffset="0" type="solid" weight="standard" color="standard" width="0.15"/>')
    assert np.all(marks.kind == KIND_CODE["roadmark"]) and np.all(marks.lane_id == -1)
    assert np.isclose(_area(marks), 30 * 0.15)
    np.testing.assert_allclose(marks.vertices[:, 1].min(), -3 - 0.075)
    np.testing.assert_allclose(marks.vertices[:, 1].max(), -3 + 0.075)
    np.testing.assert_allclose(marks.vertices[:, 2], LIFT)
    assert np.all(face_cross(marks.vertices, marks.faces)[:, 2] > 0)
    assert MARK_COLOURS[int(marks.colour[0])] == "white"


def test_broken_line_dashes_start_at_the_record():
    _odr, marks = _marks('<roadMark sOffset="2" type="broken" weight="bold" color="yellow"/>')
    # dashes of BROKEN[0] every BROKEN[0] + BROKEN[1] metres from s = 2; bold is 0.25 m wide
    period = sum(BROKEN)
    starts = np.arange(2.0, 30.0, period)
    expected = sum(min(BROKEN[0], 30.0 - a) for a in starts)
    assert np.isclose(_area(marks), expected * 0.25)
    assert {MARK_COLOURS[int(c)] for c in marks.colour} == {"yellow"}
    s = marks.uv[:, 0]
    assert s.min() >= 2.0 - 1e-9
    # no paint in the gaps
    centre_s = marks.uv[marks.faces][:, :, 0].mean(axis=1)
    phase = (centre_s - 2.0) % period
    assert np.all(phase <= BROKEN[0] + 1e-9)


@pytest.mark.parametrize("kind, lines", [("solid solid", 2), ("solid broken", 2), ("broken broken", 2)])
def test_double_lines(kind, lines):
    _odr, marks = _marks(f'<roadMark sOffset="0" type="{kind}" width="0.1"/>')
    t = marks.uv[:, 1]
    # two lines one width apart: centres at -3 +- 0.1
    assert np.isclose(t.max(), -3 + 0.1 + 0.05) and np.isclose(t.min(), -3 - 0.1 - 0.05)
    left = marks.select(marks.uv[marks.faces][:, :, 1].mean(axis=1) > -3)
    right = marks.select(marks.uv[marks.faces][:, :, 1].mean(axis=1) < -3)
    first, second = kind.split()
    assert np.isclose(_area(left), 30 * 0.1) == (first == "solid")
    assert np.isclose(_area(right), 30 * 0.1) == (second == "solid")


def test_explicit_lines_and_centre_lane_marks():
    mark = ('<roadMark sOffset="0" type="custom"><type name="mine" width="0.2">'
            '<line length="1" space="1" tOffset="0.5" sOffset="0" width="0.2" color="blue"/></type></roadMark>')
    _odr, marks = _marks(mark, centre_mark='<roadMark sOffset="0" type="solid" color="red" width="0.12"/>')
    centre = marks.select(marks.lane_id == 0)
    assert np.isclose(_area(centre), 30 * 0.12)
    np.testing.assert_allclose(np.abs(centre.vertices[:, 1]).max(), 0.06)
    custom = marks.select(marks.lane_id == -1)
    assert np.isclose(_area(custom), 15 * 0.2)
    np.testing.assert_allclose(custom.uv[:, 1].mean(), -3 + 0.5)
    colours = {MARK_COLOURS[int(c)] for c in marks.colour}
    assert colours == {"red", "blue"}


def test_botts_dots_are_boxes():
    _odr, marks = _marks('<roadMark sOffset="0" type="botts dots"/>')
    dots = len(marks.faces) // 10
    assert dots == 30
    assert np.isclose(marks.vertices[:, 2].max(), LIFT + DOT_HEIGHT / 2)
    top = marks.select(face_cross(marks.vertices, marks.faces)[:, 2] > 0)
    assert np.isclose(_area(top), dots * DOT_SIZE ** 2)


def test_marks_follow_curves_elevation_and_skip_nothing_types():
    geometry = '<geometry s="0" x="0" y="0" hdg="0" length="60"><arc curvature="0.05"/></geometry>'
    extra = '<elevationProfile><elevation s="0" a="3" b="0.04" c="0" d="0"/></elevationProfile>'
    odr, marks = _marks('<roadMark sOffset="0" type="solid" width="0.12"/><roadMark sOffset="20" type="none"/>'
                        '<roadMark sOffset="40" type="curb"/>', geometry=geometry, length=60.0, extra=extra)
    assert marks.uv[:, 0].max() <= 20 + 1e-9
    road = odr.roads[0]
    exact = road.surface_point(marks.uv[:, 0], marks.uv[:, 1])
    # vertices are the exact surface points lifted by LIFT along the surface normal
    np.testing.assert_allclose(np.linalg.norm(marks.vertices - exact, axis=1), LIFT, atol=1e-9)
