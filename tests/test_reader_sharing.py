"""The reader shares what repeats across a city's lanes (cubic profiles, plain road marks and lane records, their
tuples, attribute dicts) -- but only what is the same bit for bit: a -0.0 is not a 0.0, a mark of another
section start is not the same mark."""

from __future__ import annotations

import numpy as np
import pytest

from tavf_mapkit.opendrive import loads_opendrive
from tavf_mapkit.opendrive.writer import to_xml

_LANE = ('<lane id="{id}" type="driving" level="false"><link><predecessor id="{id}"/></link>'
         '<width sOffset="0" a="{a}" b="0" c="0" d="0"/>'
         '<roadMark sOffset="0" type="solid" weight="standard" color="standard" width="0.13"/>'
         '<speed sOffset="0" max="13.89"/></lane>')


def _xml(widths: list[str], section_starts: list[float]) -> str:
    roads = []
    for r, (a, s0) in enumerate(zip(widths, section_starts)):
        sections = '<laneSection s="0"><center><lane id="0" type="none"/></center><right>' \
                   + _LANE.format(id=-1, a=a) + _LANE.format(id=-2, a=a) + "</right></laneSection>"
        if s0 > 0:
            sections += f'<laneSection s="{s0}"><center><lane id="0" type="none"/></center><right>' \
                        + _LANE.format(id=-1, a=a) + "</right></laneSection>"
        roads.append(f'<road id="{r}" length="20.0" junction="-1"><planView><geometry s="0" x="{r * 50.0}" y="0" '
                     f'hdg="0" length="20.0"><line/></geometry></planView><elevationProfile>'
                     f'<elevation s="0" a="0" b="0" c="0" d="0"/></elevationProfile><lanes>{sections}</lanes></road>')
    return '<?xml version="1.0"?>\n<OpenDRIVE><header revMajor="1" revMinor="6"/>' + "".join(roads) \
        + "</OpenDRIVE>\n"


@pytest.fixture(scope="module")
def odr():
    return loads_opendrive(_xml(["3.2", "3.2", "-0.0", "0.0", "3.2"], [0.0, 10.0, 0.0, 0.0, 5.0]))


def _lanes(road, section=0):
    return {lane.id: lane for lane in road.lane_sections[section].lanes}


def test_identical_values_are_one_object(odr):
    first, second = _lanes(odr.roads[0])[-1], _lanes(odr.roads[1])[-2]
    assert first.widths is second.widths  # 3.2 m from s=0 on both
    assert first.road_marks is second.road_marks and first.road_marks[0] is second.road_marks[0]
    assert first.records is second.records
    assert odr.roads[0].elevation is odr.roads[4].elevation
    assert odr.roads[0].lane_sections[0].attrib is odr.roads[2].lane_sections[0].attrib
    assert not first.widths.s0.flags.writeable and not first.widths.coefficients.flags.writeable


def test_only_bit_identical_values_are_shared(odr):
    negative, positive = _lanes(odr.roads[2])[-1].widths, _lanes(odr.roads[3])[-1].widths
    assert negative is not positive
    assert np.signbit(negative.coefficients[0, 0]) and not np.signbit(positive.coefficients[0, 0])
    # a mark of a section starting at s=10 is at s=10, not the one at s=0 of the same attributes
    late = _lanes(odr.roads[1], 1)[-1]
    assert late.road_marks[0].s_offset == 10.0 and late.records[0].s0 == 10.0
    assert late.widths.s0[0] == 10.0 and late.widths is not _lanes(odr.roads[4], 1)[-1].widths
    # every lane keeps its own source line and links
    lines = [lane.line for road in odr.roads for section in road.lane_sections for lane in section.lanes]
    assert all(line is not None for line in lines)


def test_shared_values_write_back_as_read(odr):
    text = to_xml(odr)
    assert to_xml(loads_opendrive(text)) == text
    assert text.count(b'a="-0"') == 2 and text.count(b'sOffset="0"') > 0
