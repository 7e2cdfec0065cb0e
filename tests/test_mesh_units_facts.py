"""MeshUnits' whole-map facts (found once, asked per batch) agree with reading them off the roads one by one."""

import numpy as np
import shapely

from tavf_mapkit.mesh.kinds import lane_kind_codes
from tavf_mapkit.mesh.lanes import raised_lane_rows
from tavf_mapkit.mesh.units import mesh_units
from tavf_mapkit.opendrive import load_opendrive


def test_units_facts_match_the_roads(sample_build_dir):
    odr = load_opendrive(sample_build_dir / f"{sample_build_dir.name}.xodr")
    units = mesh_units(odr)
    roads = odr.roads
    assert units.in_junction.tolist() == [road.in_junction for road in roads] and units.in_junction.any()
    assert units.road_junction.tolist() == [road.junction if road.in_junction else "" for road in roads]
    first = {}
    for index, road in enumerate(roads):
        first.setdefault(road.junction, index)
    assert units.junction_first_road == {j: first[j] for j in {r.junction for r in roads if r.in_junction}}
    assert np.array_equal(units.lane_kind, lane_kind_codes(odr.arrays.lane_type))
    assert np.array_equal(units.raised_rows, raised_lane_rows(odr.arrays))


def test_roads_meeting_is_the_box_tree_query(sample_build_dir):
    odr = load_opendrive(sample_build_dir / f"{sample_build_dir.name}.xodr")
    units = mesh_units(odr)
    boxes = shapely.box(*units.road_box.T)
    tree = shapely.STRtree(boxes)
    rng = np.random.default_rng(3)
    for size in (1, 5, len(boxes)):
        chosen = np.sort(rng.choice(len(boxes), size=size, replace=False))
        _, near = tree.query(boxes[chosen], predicate="intersects")
        assert np.array_equal(units.roads_meeting(chosen), np.unique(near))
    assert len(units.roads_meeting(np.zeros(0, dtype=np.int64))) == 0
