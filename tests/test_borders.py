"""The map's flat tables are the one definition of its geometry; the per-road path must agree with them.

A property test over generated roads (hypothesis): lane sections with width or border records, lane offsets,
elevation and a reference line of lines, arcs and spirals. For each road, ``Road.lane_borders`` (per section,
per lane), ``Road.reference_point`` and ``CubicProfile`` evaluate exactly what ``border_offsets``,
``NetworkArrays.reference`` and ``RecordTable`` give for the same (road, s) -- and whole-section sampling
(``border_offsets`` with ``inner_pair``) equals the walk from the centre.
"""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tavf_mapkit.opendrive.borders import border_offsets
from tavf_mapkit.opendrive.reader import loads_opendrive
from tavf_mapkit.opendrive.sampling import sample_lanes
from xodr_factory import document, road_xml

_coefficient = st.floats(-0.05, 0.05, allow_nan=False)
_width = st.floats(0.5, 4.5, allow_nan=False)


@st.composite
def _cubic(draw, tag: str, s: float, base) -> str:
    a = draw(base)
    b, c, d = (draw(_coefficient) for _ in range(3))
    return f'<{tag} {"sOffset" if tag in ("width", "border") else "s"}="{s!r}" a="{a!r}" b="{b!r}" c="{c * 0.1!r}" d="{d * 0.01!r}"/>'


@st.composite
def _lane(draw, lane_id: int, length: float) -> str:
    tag = draw(st.sampled_from(["width", "width", "border"]))
    side = 1 if lane_id > 0 else -1
    base = _width if tag == "width" else st.floats(0.5, 12.0, allow_nan=False).map(lambda t: side * t)
    starts = sorted({0.0, *draw(st.lists(st.floats(0.0, length, allow_nan=False), max_size=2))})
    records = "".join(draw(_cubic(tag, s, base)) for s in starts)
    return f'<lane id="{lane_id}" type="driving" level="false">{records}</lane>'


@st.composite
def _road(draw, road_id: str) -> str:
    length = draw(st.floats(5.0, 80.0, allow_nan=False))
    kind = draw(st.sampled_from(["line", "arc", "spiral"]))
    shape = {"line": "<line/>", "arc": f'<arc curvature="{draw(st.floats(-0.05, 0.05))!r}"/>',
             "spiral": f'<spiral curvStart="{draw(st.floats(-0.02, 0.02))!r}" '
                       f'curvEnd="{draw(st.floats(-0.02, 0.02))!r}"/>'}[kind]
    x, y, hdg = draw(st.floats(-500.0, 500.0)), draw(st.floats(-500.0, 500.0)), draw(st.floats(-3.0, 3.0))
    geometry = f'<geometry s="0" x="{x!r}" y="{y!r}" hdg="{hdg!r}" length="{length!r}">{shape}</geometry>'
    cuts = sorted({0.0, *draw(st.lists(st.floats(1.0, length - 1.0), max_size=2))})
    sections = []
    for s0 in cuts:
        left = draw(st.integers(0, 3))
        right = draw(st.integers(1, 3))
        left_lanes = "".join(draw(_lane(i, length)) for i in range(left, 0, -1))
        right_lanes = "".join(draw(_lane(-i, length)) for i in range(1, right + 1))
        sections.append(f'<laneSection s="{s0!r}">' + (f"<left>{left_lanes}</left>" if left else "")
                        + '<center><lane id="0" type="none" level="false"/></center>'
                        + f"<right>{right_lanes}</right></laneSection>")
    offsets = "".join(draw(_cubic("laneOffset", s, st.floats(-2.0, 2.0)))
                      for s in sorted({0.0, *draw(st.lists(st.floats(0.0, length), max_size=2))}))
    elevation = "".join(draw(_cubic("elevation", s, st.floats(-5.0, 5.0)))
                        for s in sorted({0.0, *draw(st.lists(st.floats(0.0, length), max_size=2))}))
    return road_xml(geometry, length, "".join(sections), extra=f"<elevationProfile>{elevation}</elevationProfile>",
                    road_id=road_id, lane_offset=offsets)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(roads=st.lists(st.integers(0, 10**6), min_size=1, max_size=3).flatmap(
    lambda ids: st.tuples(*(_road(f"r{k}") for k in range(len(ids))))),
    fractions=st.lists(st.floats(0.0, 1.0), min_size=1, max_size=8))
def test_the_per_road_path_agrees_with_the_tables(roads, fractions):
    odr = loads_opendrive(document(*roads))
    arrays = odr.arrays
    for road_index, road in enumerate(odr.roads):
        s = np.array(fractions) * road.length
        # reference line and profiles: per road vs the whole-map tables
        per_road = road.reference_point(s)
        tables = arrays.reference(np.full(len(s), road_index), s)
        for a, b in zip(per_road, tables[:6]):
            np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(road.lane_offset(s), tables[6])
        # lane borders of every section, inside the section's own s range
        for k, section in enumerate(road.lane_sections):
            s_in = road.section_starts[k] + np.array(fractions) * (road.section_end(k) - road.section_starts[k])
            per_road = road.lane_borders(k, s_in)
            section_row = np.flatnonzero((arrays.section_road == road_index))[k]
            for row in np.flatnonzero(arrays.lane_section == section_row):
                lane_id = int(arrays.lane_id[row])
                t_inner, t_outer = border_offsets(arrays, np.full(len(s_in), row), s_in)
                np.testing.assert_allclose(t_outer, per_road[lane_id], rtol=0, atol=1e-9)
                inner_id = lane_id - np.sign(lane_id)
                np.testing.assert_allclose(t_inner, per_road[int(inner_id)], rtol=0, atol=1e-9)


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(roads=st.lists(st.integers(0, 10**6), min_size=1, max_size=3).flatmap(
    lambda ids: st.tuples(*(_road(f"r{k}") for k in range(len(ids))))))
def test_whole_section_sampling_equals_walking_out_from_the_centre(roads):
    odr = loads_opendrive(document(*roads))
    sampling = sample_lanes(odr, 0.7)
    t_inner, t_outer = border_offsets(odr.arrays, sampling.pair_lane, sampling.s)
    np.testing.assert_array_equal(t_inner, sampling.t_inner)
    np.testing.assert_array_equal(t_outer, sampling.t_outer)
