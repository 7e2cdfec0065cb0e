"""Simulated GNSS against the map's georeference, IMU, and the lidar/camera on a pybullet scene."""

from __future__ import annotations

import math

import numpy as np
import pybullet as pb
import pytest

from tavf_mapkit.opendrive.georef import GeoReference
from tavf_mapkit.opendrive.header import Offset
from twin.sensors.camera import CameraConfig, CameraSensor
from twin.sensors.gnss import GnssConfig, GnssSensor
from twin.sensors.lidar import LidarConfig, LidarSensor
from twin.sensors.odometry import ImuConfig, ImuSensor

TMERC = "+proj=tmerc +lat_0=53.5562874 +lon_0=9.9812247 +k=1 +x_0=0 +y_0=0 +ellps=WGS84 +units=m +no_defs"


def _georef(offset=None):
    return GeoReference(TMERC, offset)


@pytest.mark.parametrize("offset", [None, Offset(512.5, -301.25, 10.0, 0.0)])
def test_zero_noise_fix_converts_back_within_a_millimetre(offset):
    georef = _georef(offset)
    gnss = GnssSensor(georef, GnssConfig(), np.random.default_rng(1), 0.05)
    rng = np.random.default_rng(7)
    x, y, z = rng.uniform(-3000, 3000, 200), rng.uniform(-3000, 3000, 200), rng.uniform(0, 30, 200)
    lat, lon, alt, *_ = gnss.measure_many(0.0, x, y, z)
    back_x, back_y = georef.wgs84_to_local(lon, lat)
    assert np.max(np.hypot(back_x - x, back_y - y)) <= 1e-3
    assert np.allclose(alt, z + (offset.z if offset else 0.0))


def test_noise_sigma_is_the_sample_standard_deviation():
    georef = _georef()
    sigma = 0.8
    gnss = GnssSensor(georef, GnssConfig(sigma=(sigma, sigma, 2 * sigma)), np.random.default_rng(3), 0.05)
    n = 10_000
    x, y, z = np.full(n, 120.0), np.full(n, -40.0), np.full(n, 5.0)
    lat, lon, alt, *_ = gnss.measure_many(0.0, x, y, z)
    ex, ny = georef.wgs84_to_local(lon, lat)
    for errors, expected in ((ex - x, sigma), (ny - y, sigma), (alt - z, 2 * sigma)):
        assert abs(np.std(errors, ddof=1) / expected - 1.0) < 0.05
        assert abs(np.mean(errors)) < 4 * expected / math.sqrt(n)


def test_bias_and_seed():
    georef = _georef()
    config = GnssConfig(sigma=(0.5, 0.5, 0.5), bias=(1.0, -2.0, 0.5))
    a = GnssSensor(georef, config, np.random.default_rng(11), 0.05).measure_many(0, np.zeros(5000), np.zeros(5000),
                                                                               np.zeros(5000))
    b = GnssSensor(georef, config, np.random.default_rng(11), 0.05).measure_many(0, np.zeros(5000), np.zeros(5000),
                                                                               np.zeros(5000))
    assert all(np.array_equal(u, v) for u, v in zip(a, b))
    assert np.mean(a[3]) == pytest.approx(1.0, abs=0.03) and np.mean(a[4]) == pytest.approx(-2.0, abs=0.03)


def test_rate():
    gnss = GnssSensor(_georef(), GnssConfig(rate_hz=5.0), np.random.default_rng(0), 0.05)
    assert [s for s in range(20) if gnss.due(s)] == [0, 4, 8, 12, 16]
    with pytest.raises(ValueError):
        GnssSensor(None, GnssConfig(), np.random.default_rng(0), 0.05)


def test_imu_reports_centripetal_acceleration():
    imu = ImuSensor(ImuConfig(0.0, 0.0, 0.0), np.random.default_rng(0), 0.05)
    imu.measure(0.0, 10.0, 0.0, 0.2, 0.0)
    sample = imu.measure(0.05, 10.0, 0.0, 0.2, 0.0)
    assert sample.accel_y == pytest.approx(10.0 * 0.2) and sample.accel_x == pytest.approx(0.0)
    assert sample.speed == 10.0 and sample.yaw_rate == 0.2


@pytest.fixture
def scene():
    cid = pb.connect(pb.DIRECT)
    pb.createMultiBody(0, pb.createCollisionShape(pb.GEOM_PLANE, physicsClientId=cid), physicsClientId=cid)
    wall = pb.createMultiBody(0, pb.createCollisionShape(pb.GEOM_BOX, halfExtents=[0.5, 20.0, 5.0],
                                                         physicsClientId=cid),
                              basePosition=[20.5 - 100.0, 0.0, 5.0], physicsClientId=cid)
    yield cid, wall
    pb.disconnect(cid)


def test_lidar_measures_the_distance_to_a_wall(scene):
    cid, wall = scene
    # the map frame is shifted by origin (100, 0, 0): the wall's face is at map x = 20
    lidar = LidarSensor(cid, LidarConfig(channels=32, columns=1024), 0.05, origin=(100.0, 0.0, 0.0))
    scan = lidar.scan(0.0, 0.0, 0.0, 0.0, 0.0)
    assert scan.ranges.shape == (32, 1024)
    forward = scan.ranges[:, 0]  # azimuth 0 looks along +x
    elevation = np.radians(np.linspace(-25.0, 15.0, 32))
    level = elevation > -math.atan(1.9 / 20.0)  # rays that reach the wall before the ground
    assert np.allclose(forward[level], 20.0 / np.cos(elevation[level]), atol=1e-3)
    hits_on_wall = scan.points[scan.bodies == wall]
    assert np.allclose(hits_on_wall[:, 0], 20.0, atol=1e-3)


def test_camera_sees_the_wall(scene):
    cid, _ = scene
    camera = CameraSensor(cid, CameraConfig(width=64, height=48), 0.05, origin=(100.0, 0.0, 0.0))
    image = camera.capture(0.0, 0.0, 0.0, 0.0, 0.0)
    assert image.rgb.shape == (48, 64, 3) and image.rgb.dtype == np.uint8
    looking_away = camera.capture(0.0, 0.0, 0.0, 0.0, math.pi)
    assert not np.array_equal(image.rgb, looking_away.rgb)


def test_embree_lidar_agrees_with_pybullet_rays_and_sees_moving_bodies(sample_build_dir):
    pytest.importorskip("embreex")
    from tavf_mapkit.world import load
    from twin.sensors.embree import EmbreeWorld

    cid = pb.connect(pb.DIRECT)
    try:
        world = load(sample_build_dir, cid)
        origin = world.origin
        config = LidarConfig(channels=16, columns=512)
        plain = LidarSensor(cid, config, 0.05, origin=origin)
        fast = LidarSensor(cid, config, 0.05, origin=origin,
                           embree=EmbreeWorld(sample_build_dir / "collision", world))
        # a car-sized box 8 m ahead that is not part of the static world (like a SUMO vehicle)
        pose = (-2.0, 150.0, 0.0, -math.pi / 2)
        box = pb.createMultiBody(0, pb.createCollisionShape(pb.GEOM_BOX, halfExtents=[1.0, 2.4, 0.8],
                                                            physicsClientId=cid),
                                 basePosition=(np.array([-2.0, 142.0, 0.8]) - origin).tolist(), physicsClientId=cid)
        a, b = plain.scan(0.0, *pose), fast.scan(0.0, *pose)
        both = np.isfinite(a.ranges) & np.isfinite(b.ranges)
        assert np.mean(np.isfinite(a.ranges) == np.isfinite(b.ranges)) > 0.999
        assert np.percentile(np.abs(a.ranges[both] - b.ranges[both]), 99.9) < 1e-3
        assert np.count_nonzero(b.bodies == box) == np.count_nonzero(a.bodies == box) > 50
    finally:
        pb.disconnect(cid)
