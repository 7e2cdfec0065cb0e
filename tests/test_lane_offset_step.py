"""A laneOffset that steps exactly at a lane-section boundary belongs to the section that starts there.

CARLA's maps (Town03, Town07) do this: where lanes of type "none" appear beside a driving lane, the laneOffset
jumps by their width so that the driving lane itself does not move. Evaluated at the previous section's end,
the new record must not be in force yet, or that section's lanes end several metres sideways (a kink in every
path, mesh and lane graph built from it).
"""

from __future__ import annotations

import numpy as np
import pytest

from tavf_mapkit.opendrive import loads_opendrive
from tests.xodr_factory import document, road_xml

LANES = """
    <laneOffset s="0" a="0" b="0" c="0" d="0"/>
    <laneOffset s="20" a="8" b="0" c="0" d="0"/>
    <laneSection s="0">
      <center><lane id="0" type="none" level="false"/></center>
      <right><lane id="-1" type="driving" level="false"><link><successor id="-3"/></link>
        <width sOffset="0" a="3.5" b="0" c="0" d="0"/></lane></right>
    </laneSection>
    <laneSection s="20">
      <center><lane id="0" type="none" level="false"/></center>
      <right>
        <lane id="-1" type="none" level="false"><width sOffset="0" a="4.5" b="0" c="0" d="0"/></lane>
        <lane id="-2" type="none" level="false"><width sOffset="0" a="3.5" b="0" c="0" d="0"/></lane>
        <lane id="-3" type="driving" level="false"><link><predecessor id="-1"/></link>
          <width sOffset="0" a="3.5" b="0" c="0" d="0"/></lane>
      </right>
    </laneSection>"""


@pytest.fixture
def odr():
    geometry = '<geometry s="0" x="0" y="0" hdg="0" length="40"><line/></geometry>'
    return loads_opendrive(document(road_xml(geometry, 40.0, lanes=LANES)))


def test_lane_borders_at_the_section_end_use_the_sections_own_offset(odr):
    road = odr.roads[0]
    assert road.lane_borders(0, [20.0])[-1][0] == pytest.approx(-3.5)
    assert road.lane_borders(1, [20.0])[-3][0] == pytest.approx(8.0 - 4.5 - 3.5 - 3.5)


def test_sampled_lanes_and_lane_graph_do_not_jump(odr):
    from tavf_mapkit.lanegraph import LaneGraph, LaneKey
    from tavf_mapkit.opendrive.sampling import sample_lanes

    sampling = sample_lanes(odr, step=1.0)
    first = (sampling.pair_lane == 0)  # lane -1 of section 0: its border stays at t = -3.5 up to s = 20
    assert np.allclose(sampling.t_outer[first], -3.5)
    graph = LaneGraph.from_opendrive(odr)
    before, after = LaneKey(0, 0, -1), LaneKey(0, 1, -3)
    assert graph.successors(before) == [after]
    end, start = np.array(graph.end(before)), np.array(graph.start(after))
    assert np.hypot(*(end - start)) < 1e-9
    points, _ = graph.centerline(before, step=1.0)
    assert np.allclose(points[:, 1], -1.75)
