"""Georeference: PROJ strings, the header offset's sign, plausibility, and agreement with sumolib."""

from __future__ import annotations

import numpy as np
import pytest

from tavf_mapkit.opendrive import load_opendrive, loads_opendrive
from tavf_mapkit.opendrive.georef import GeoReference, normalise_proj_text
from tavf_mapkit.opendrive.header import Offset
from tests.conftest import shared_path
from tests.xodr_factory import document, road_xml


@pytest.mark.slow
def test_wgs84_of_netconvert_opendrive_agrees_with_sumolib(tavf_xodr):
    """Lane shapes of the TAVF net, through netconvert's OpenDRIVE and our reader, vs sumolib on the same net."""
    import sumolib

    net = sumolib.net.readNet(str(shared_path("hamburg", "tavf_dlr_sumo_net", "network.net.xml.gz")),
                              withInternal=False)
    odr = load_opendrive(tavf_xodr)
    geo = odr.georeference
    assert geo is not None and geo.offset is not None
    # netconvert writes the negated SUMO netOffset into <offset>: projected = local + offset
    net_offset = net.getLocationOffset()
    assert geo.offset.x == pytest.approx(-net_offset[0]) and geo.offset.y == pytest.approx(-net_offset[1])
    # the OpenDRIVE local frame is SUMO's network frame: convert the same local points both ways
    rng = np.random.default_rng(1)
    points = []
    for edge in rng.choice(net.getEdges(), 200, replace=False):
        for lane in edge.getLanes():
            points.extend(lane.getShape())
    points = np.array(points)
    lon, lat = geo.local_to_wgs84(points[:, 0], points[:, 1])
    expected = np.array([net.convertXY2LonLat(x, y) for x, y in points])
    # compare in metres
    east, north = geo.wgs84_to_local(expected[:, 0], expected[:, 1])
    distance = np.hypot(east - points[:, 0], north - points[:, 1])
    assert distance.max() < 0.05
    assert np.abs(lon - expected[:, 0]).max() < 1e-6 and np.abs(lat - expected[:, 1]).max() < 1e-6


def test_lane_positions_of_netconvert_opendrive_lie_on_sumo_lanes(tavf_xodr):
    """Independent check: OpenDRIVE lane centres (our reader) vs sumolib lane shapes of the same net."""
    import sumolib
    from shapely import STRtree, LineString, points as shapely_points

    from tavf_mapkit.opendrive.sampling import sample_lanes

    net = sumolib.net.readNet(str(shared_path("hamburg", "tavf_dlr_sumo_net", "network.net.xml.gz")),
                              withInternal=True)
    shapes = [LineString(lane.getShape()) for edge in net.getEdges(withInternal=True) for lane in edge.getLanes()
              if len(lane.getShape()) >= 2]
    tree = STRtree(shapes)
    sampling = sample_lanes(load_opendrive(tavf_xodr), 2.0)
    centre = sampling.center_points()
    # lon/lat are irrelevant here: both live in SUMO's network frame
    query = shapely_points(centre[:, 0], centre[:, 1])
    _, distance = tree.query_nearest(query, return_distance=True, all_matches=False)
    assert np.median(distance) < 0.05
    assert np.quantile(distance, 0.95) < 0.5


def test_offset_sign_and_rotation():
    geo = GeoReference("+proj=utm +zone=32 +ellps=WGS84 +units=m +no_defs", Offset(500000.0, 5930000.0, 0.0, np.pi / 2))
    px, py = geo.local_to_projected(np.array([10.0]), np.array([0.0]))
    assert px[0] == pytest.approx(500000.0) and py[0] == pytest.approx(5930010.0)
    x, y = geo.projected_to_local(px, py)
    assert x[0] == pytest.approx(10.0) and y[0] == pytest.approx(0.0, abs=1e-9)
    lon, lat = geo.local_to_wgs84([0.0], [0.0])
    assert lon[0] == pytest.approx(9.0, abs=1e-6)  # UTM 32 central meridian
    back = geo.wgs84_to_local(lon, lat)
    assert np.hypot(back[0][0], back[1][0]) < 1e-6


def test_carla_style_and_epsg():
    assert normalise_proj_text("+lat_0=53.55 +lon_0=9.99").startswith("+proj=tmerc +lat_0=53.55 +lon_0=9.99")
    geo = GeoReference("+lat_0=53.55 +lon_0=9.99")
    lon, lat = geo.local_to_wgs84([0.0], [0.0])
    assert (lon[0], lat[0]) == (pytest.approx(9.99), pytest.approx(53.55))
    assert geo.carla_readable()
    epsg = GeoReference("EPSG:25832", Offset(565000.0, 5934000.0))
    lon, lat = epsg.local_to_wgs84([0.0], [0.0])
    assert 9.9 < lon[0] < 10.1 and 53.5 < lat[0] < 53.6
    assert not epsg.carla_readable()


def test_contradictory_georeference_is_reported():
    odr = load_opendrive(shared_path("xodr", "esmini", "e6mini.xodr"))
    problems = odr.georeference.plausibility(odr.bounds())
    assert any("contradicts itself" in p for p in problems)


def test_plausible_georeference_and_bounds_outside_area_of_use():
    header = '<geoReference><![CDATA[EPSG:25832]]></geoReference><offset x="565000" y="5934000" z="0" hdg="0"/>'
    line = '<geometry s="0" x="0" y="0" hdg="0" length="100"><line/></geometry>'
    odr = loads_opendrive(document(road_xml(line, 100), header_extra=header))
    assert odr.georeference.plausibility(odr.bounds()) == []
    far = header.replace('x="565000"', 'x="-9000000"')
    odr = loads_opendrive(document(road_xml(line, 100), header_extra=far))
    assert odr.georeference.plausibility(odr.bounds())


def test_unparseable_georeference_is_an_input_error():
    from tavf_mapkit.errors import InputError

    geo = GeoReference("+proj=nonsense +foo")
    with pytest.raises(InputError, match="geoReference is not a valid PROJ"):
        geo.local_to_wgs84([0.0], [0.0])
