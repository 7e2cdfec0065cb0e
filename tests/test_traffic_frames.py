"""SUMO network <-> OpenDRIVE local coordinates, checked against sumolib's own projection both ways."""

from __future__ import annotations

import math

import numpy as np
import pyproj
import pytest
import sumolib

from tavf_mapkit.errors import InputError
from twin.traffic.buildfiles import build_files
from twin.traffic.frames import NetFrame, wrap_angle

TMERC = "+proj=tmerc +lat_0=53.5529609 +lon_0=9.9954083 +k=1 +x_0=0 +y_0=0 +ellps=WGS84 +units=m +no_defs"
UTM32 = "+proj=utm +zone=32 +ellps=WGS84 +datum=WGS84 +units=m +no_defs"


def write_pair(folder, net_offset, net_proj, xodr_proj, xodr_offset):
    """A minimal NAME.net.xml (just <location>) and NAME.xodr (just the header) in ``folder``."""
    net = folder / "m.net.xml"
    net.write_text(
        '<?xml version="1.0"?>\n<net version="1.20">\n'
        f'  <location netOffset="{net_offset[0]:.4f},{net_offset[1]:.4f}" convBoundary="0,0,1000,1000" '
        f'origBoundary="9.98,53.54,10.01,53.56" projParameter="{net_proj}"/>\n'
        '  <edge id="e" from="a" to="b"><lane id="e_0" index="0" speed="13.9" length="10" shape="0,0 10,0"/></edge>\n'
        '</net>\n', encoding="utf-8")
    georef = f"<geoReference><![CDATA[{xodr_proj}]]></geoReference>" if xodr_proj else ""
    offset = ""
    if xodr_offset is not None:
        ox, oy, hdg = xodr_offset
        offset = f'<offset x="{ox}" y="{oy}" z="0" hdg="{hdg}"/>'
    xodr = folder / "m.xodr"
    xodr.write_text(f'<?xml version="1.0"?>\n<OpenDRIVE><header revMajor="1" revMinor="6">{georef}{offset}'
                    '</header></OpenDRIVE>\n', encoding="utf-8")
    return net, xodr


def sumolib_net(net_offset, proj):
    net = sumolib.net.Net()
    net.setLocation(f"{net_offset[0]:.4f},{net_offset[1]:.4f}", "0,0,1000,1000", "9.98,53.54,10.01,53.56", proj)
    return net


def sumolib_lonlat(net, x, y):
    return np.array([net.convertXY2LonLat(float(a), float(b)) for a, b in zip(x, y)])


def random_points(rng, boundary, n=200):
    west, south, east, north = boundary
    return rng.uniform(west, east, n), rng.uniform(south, north, n)


@pytest.mark.slow  # sumolib reads the whole network (TAVF: ~10 s)
@pytest.mark.parametrize("fixture", ["jungfernstieg_build", "tavf_dlr_build"])
def test_real_builds_agree_with_sumolib_and_round_trip(fixture, request):
    build = request.getfixturevalue(fixture)
    files = build_files(build)
    frame = NetFrame.from_build(build)
    reference = sumolib.net.readNet(str(files.net))
    rng = np.random.default_rng(1)
    x, y = random_points(rng, reference.getBoundary())
    lx, ly = frame.net_to_local(x, y)
    lon, lat = frame.local_to_wgs84(lx, ly)
    expected = sumolib_lonlat(reference, x, y)
    assert np.max(np.abs(np.column_stack([lon, lat]) - expected)) < 1e-9  # ~0.1 mm
    back_x, back_y = frame.local_to_net(lx, ly)
    assert np.max(np.hypot(back_x - x, back_y - y)) < 1e-9


@pytest.mark.parametrize("xodr_offset", [
    None,  # normalised: local (0,0) at the projection origin... and netOffset kept by SUMO
    (-490.18, -465.42, 0.0),  # netconvert 1.28 without normalisation: local == net
    (120.5, -33.25, 0.3),  # an offset with a heading: a rotated local frame
])
def test_same_projection_is_exact_for_any_offset(tmp_path, xodr_offset):
    net_offset = (490.18, 465.42)
    net_path, xodr_path = write_pair(tmp_path, net_offset, TMERC, TMERC, xodr_offset)
    frame = NetFrame.from_files(net_path, xodr_path)
    assert frame.exact
    rng = np.random.default_rng(2)
    x, y = random_points(rng, (0, 0, 1000, 1000))
    lx, ly = frame.net_to_local(x, y)
    expected = sumolib_lonlat(sumolib_net(net_offset, TMERC), x, y)
    lon, lat = frame.local_to_wgs84(lx, ly)
    assert np.max(np.abs(np.column_stack([lon, lat]) - expected)) < 1e-9
    back = frame.local_to_net(lx, ly)
    assert np.max(np.hypot(back[0] - x, back[1] - y)) < 1e-9
    if xodr_offset == (-490.18, -465.42, 0.0):
        assert np.max(np.hypot(lx - x, ly - y)) < 1e-9


def test_different_projections_go_through_pyproj(tmp_path):
    # the SUMO network in UTM 32N (as DLR's TAVF network ships), the OpenDRIVE map in a local tmerc
    net_offset = (-562751.27, -5932801.54)
    net_path, xodr_path = write_pair(tmp_path, net_offset, UTM32, TMERC, (10.0, -5.0, 0.0))
    frame = NetFrame.from_files(net_path, xodr_path)
    assert not frame.exact
    rng = np.random.default_rng(3)
    x, y = random_points(rng, (0, 0, 3000, 3000))
    lx, ly = frame.net_to_local(x, y)
    expected = sumolib_lonlat(sumolib_net(net_offset, UTM32), x, y)
    lon, lat = frame.local_to_wgs84(lx, ly)
    assert np.max(np.abs(np.column_stack([lon, lat]) - expected)) < 1e-9
    back = frame.local_to_net(lx, ly)
    assert np.max(np.hypot(back[0] - x, back[1] - y)) < 1e-6

    # headings: SUMO's 0 deg is UTM grid north, which near 10 E is turned against the tmerc grid by the
    # meridian convergence difference; a direction measured from two projected points must agree.
    yaw = frame.sumo_angle_to_yaw(np.zeros_like(x), x, y)
    tip = frame.net_to_local(x, y + 1.0)
    measured = np.arctan2(tip[1] - ly, tip[0] - lx)
    assert np.max(np.abs(wrap_angle(yaw - measured))) < 1e-6
    assert abs(math.degrees(float(np.mean(yaw))) - 90.0) > 0.01  # the turn is real, not the identity
    angles = rng.uniform(0, 360, len(x))
    again = frame.yaw_to_sumo_angle(frame.sumo_angle_to_yaw(angles, x, y), lx, ly)
    assert np.max(np.abs(wrap_angle(np.radians(again - angles)))) < 1e-7


def test_headings_and_compass_in_the_exact_case(tmp_path):
    net_path, xodr_path = write_pair(tmp_path, (490.18, 465.42), TMERC, TMERC, None)
    frame = NetFrame.from_files(net_path, xodr_path)
    x, y = np.array([490.18]), np.array([465.42])  # the projection origin: grid north is true north there
    assert frame.sumo_angle_to_yaw([0.0], x, y)[0] == pytest.approx(math.pi / 2)
    assert frame.sumo_angle_to_yaw([90.0], x, y)[0] == pytest.approx(0.0)
    lx, ly = frame.net_to_local(x, y)
    assert frame.yaw_to_sumo_angle([math.pi], lx, ly)[0] == pytest.approx(270.0)
    assert frame.compass_heading([math.pi / 2], lx, ly)[0] == pytest.approx(0.0, abs=1e-6)
    # 1 km east of the central meridian grid north differs from true north by the convergence
    east = frame.compass_heading([math.pi / 2], lx + 1000.0, ly)[0]
    geod = pyproj.Geod(ellps="WGS84")
    lon0, lat0 = frame.local_to_wgs84(lx + 1000.0, ly)
    lon1, lat1 = frame.local_to_wgs84(lx + 1000.0, ly + 10.0)
    assert east == pytest.approx(geod.inv(lon0, lat0, lon1, lat1)[0] % 360, abs=1e-6)
    assert 0.0 < (east + 180) % 360 - 180 < 0.02 or -0.02 < (east + 180) % 360 - 180 < 0.0


def test_one_georeferenced_file_is_refused(tmp_path):
    net_path, xodr_path = write_pair(tmp_path, (0, 0), TMERC, None, None)
    with pytest.raises(InputError, match="SUMO network .* is georeferenced but the OpenDRIVE file .* is not"):
        NetFrame.from_files(net_path, xodr_path)
    net_path, xodr_path = write_pair(tmp_path, (0, 0), "!", TMERC, None)
    with pytest.raises(InputError, match="OpenDRIVE file .* is georeferenced but the SUMO network .* is not"):
        NetFrame.from_files(net_path, xodr_path)


def test_neither_georeferenced_maps_through_net_offset(tmp_path):
    net_path, xodr_path = write_pair(tmp_path, (100.0, 50.0), "!", None, (-100.0, -50.0, 0.0))
    frame = NetFrame.from_files(net_path, xodr_path)
    assert frame.exact
    lx, ly = frame.net_to_local([3.0], [4.0])
    assert (float(lx[0]), float(ly[0])) == pytest.approx((3.0, 4.0))


def test_not_a_build_folder(tmp_path):
    with pytest.raises(InputError, match="not a build folder"):
        NetFrame.from_build(tmp_path)
