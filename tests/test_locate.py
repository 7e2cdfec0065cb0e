"""(x, y) -> (road, lane, s, t): the inverse of evaluation."""

from __future__ import annotations

import numpy as np

from tavf_mapkit.opendrive import load_opendrive
from tavf_mapkit.opendrive.locate import LaneLocator
from tavf_mapkit.opendrive.sampling import sample_lanes
from tests.conftest import shared_path


def test_locate_inverts_evaluation_on_roads_outside_junctions():
    odr = load_opendrive(shared_path("xodr", "libopendrive", "test.xodr"))
    sampling = sample_lanes(odr, 3.0)
    rng = np.random.default_rng(7)
    in_junction = np.array([odr.roads[i].in_junction for i in sampling.road_index])
    wide = np.abs(sampling.t_outer - sampling.t_inner) > 1.0
    pick = rng.choice(np.flatnonzero(~in_junction & wide), 300, replace=False)
    fraction = rng.uniform(0.2, 0.8, len(pick))
    t = sampling.t_inner[pick] + fraction * (sampling.t_outer[pick] - sampling.t_inner[pick])
    xyz = np.array([odr.roads[r].surface_point([s], tt)[0]
                    for r, s, tt in zip(sampling.road_index[pick], sampling.s[pick], t)])
    location = LaneLocator(odr).locate(xyz[:, 0], xyz[:, 1])
    same = (location.road_index == sampling.road_index[pick]) & (location.lane_id == sampling.lane_id[pick])
    # a point may also lie inside an overlapping lane of another road; it must then be inside that lane
    assert np.all(location.distance[~same] < 1e-6)
    assert same.mean() > 0.9
    np.testing.assert_allclose(location.s[same], sampling.s[pick][same], atol=1e-6)
    np.testing.assert_allclose(location.t[same], t[same], atol=1e-6)
    assert np.all(location.distance[same] < 1e-6)


def test_points_off_the_road_report_their_distance():
    odr = load_opendrive(shared_path("xodr", "esmini", "straight_500m.xodr"))
    sampling = sample_lanes(odr, 10.0)
    outermost = np.max(np.abs(sampling.t_outer))
    location = LaneLocator(odr).locate([100.0], [outermost + 7.0])
    assert abs(location.distance[0] - 7.0) < 1e-6


def test_a_lane_graphs_locator_is_the_sampled_one(tavf_xodr):
    """The twin's metrics locate the ego through its lane graph's samples (a region's lanes are more than one
    allocation may sample at once): the same tree and the same locations as sampling the map again."""
    from tavf_mapkit.lanegraph import LaneGraph

    odr = load_opendrive(tavf_xodr)
    graph = LaneGraph.from_opendrive(odr)
    sampled = LaneLocator(odr, step=1.0, lane_types={"driving"})
    shared = graph.locator()
    np.testing.assert_array_equal(shared.tree.data, sampled.tree.data)
    np.testing.assert_array_equal(shared.lane_row, sampled.lane_row)
    np.testing.assert_array_equal(shared.s, sampled.s)
    rng = np.random.default_rng(3)
    low, high = sampled.tree.data.min(axis=0), sampled.tree.data.max(axis=0)
    x, y = rng.uniform(low[0], high[0], 2000), rng.uniform(low[1], high[1], 2000)
    x[:1000], y[:1000] = sampled.tree.data[::len(sampled.s) // 1000][:1000].T + rng.normal(0, 2, (2, 1000))
    a, b = shared.locate(x, y, candidates=16), sampled.locate(x, y, candidates=16)
    for field in ("road_index", "section_index", "lane_id", "s", "t", "distance"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
