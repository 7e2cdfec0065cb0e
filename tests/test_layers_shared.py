"""The report map's layers made the cheap way are the per-item ones: lanes sampled in parts
(``sample_lane_chunks``) give the whole map's sampling pair by pair, bit for bit; the junction outlines from
the junctions' lane sections alone are those of the whole map's sampling; signals and objects placed in one
evaluation through the map's arrays stand where each one's own ``Road.surface_point`` puts it, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
import shapely

from tavf_mapkit.opendrive import load_opendrive
from tavf_mapkit.opendrive.layers import lane_features, layer_features, road_mark_features
from tavf_mapkit.opendrive.sampling import sample_lane_chunks, sample_lanes

STEP = 1.0


@pytest.fixture(scope="module")
def vires():
    """VIRES' sample database: 102 signals, objects, junctions, elevation and superelevation."""
    from conftest import shared_path

    return load_opendrive(shared_path("zoo", "xodr", "vires_SampleDatabase.xodr"))


def _same_features(a, b):
    a, b = list(a), list(b)
    assert len(a) == len(b) > 0
    for x, y in zip(a, b):
        assert x.kind == y.kind and x.properties == y.properties
        assert x.coordinates.tobytes() == y.coordinates.tobytes()


@pytest.mark.parametrize("chunk_points", [1, 700, 10**9])
def test_sampling_in_parts_is_the_whole_sampling(vires, chunk_points):
    whole = sample_lanes(vires, STEP)
    parts = list(sample_lane_chunks(vires, STEP, chunk_points))
    assert (len(parts) > 1) == (chunk_points < 10**9)
    for name in ("pair_lane", "s", "t_inner", "t_outer"):
        joined = np.concatenate([getattr(part, name) for part in parts])
        assert joined.tobytes() == getattr(whole, name).tobytes(), name
    for method in ("outer_border_points", "center_points"):
        joined = np.concatenate([getattr(part, method)() for part in parts])
        assert joined.tobytes() == getattr(whole, method)().tobytes(), method


def test_lane_and_mark_features_of_parts_are_the_whole_maps(vires):
    parts = list(sample_lane_chunks(vires, STEP, 700))
    _same_features(layer_features(vires, "lane", STEP),
                   (f for part in parts for f in lane_features(vires, STEP, "lane", part)))
    _same_features(layer_features(vires, "road-mark", STEP),
                   (f for part in parts for f in road_mark_features(vires, STEP, part)))


def test_junction_outlines_of_junction_sections_are_the_whole_maps(vires):
    from tavf_mapkit.mesh.junctions import junction_footprints
    from tavf_mapkit.view.mapdata import _junction_outlines

    whole = junction_footprints(vires, sample_lanes(vires, STEP), np.zeros(len(vires.arrays.lane_id), dtype=bool))
    mine = _junction_outlines(vires, STEP)
    assert sorted(whole) == sorted(mine) and len(whole) > 0
    for key in whole:
        assert shapely.to_wkb(whole[key]) == shapely.to_wkb(mine[key]), key


@pytest.mark.parametrize("name, layer, items, least", [
    ("vires_SampleDatabase.xodr", "signal", "signals", 100),
    ("carla_Town10HD_Opt.xodr", "signal", "signals", 20),
    ("carla_Town10HD_Opt.xodr", "object", "objects", 50)])
def test_points_placed_at_once_are_each_roads_own(name, layer, items, least):
    from conftest import shared_path

    odr = load_opendrive(shared_path("zoo", "xodr", name))
    features = list(layer_features(odr, layer, STEP))
    expected = [(road.id, item.id, road.surface_point([item.s], item.t, item.z_offset))
                for road in odr.roads for item in getattr(road, items)]
    assert len(features) == len(expected) >= least
    for feature, (road_id, item_id, point) in zip(features, expected):
        assert (feature.properties["road"], feature.properties["id"]) == (road_id, item_id)
        assert feature.coordinates.tobytes() == point.tobytes()
