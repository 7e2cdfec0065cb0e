"""Trace readers: every format, real files, bags written with rosbags' own writers, broken inputs."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tavf_mapkit.errors import InputError
from tavf_mapkit.traces import read_trace

LAT = np.array([53.5500, 53.5501, 53.5502])
LON = np.array([9.9700, 9.9702, 9.9704])
T0 = 1_654_690_906.0


def test_gpx_track_with_times_and_elevation(tmp_path):
    points = "".join(f'<trkpt lat="{la}" lon="{lo}"><ele>{10 + i}</ele><time>2022-06-08T12:21:{46 + i}Z</time>'
                     f"</trkpt>" for i, (la, lo) in enumerate(zip(LAT, LON)))
    path = tmp_path / "ride.gpx"
    path.write_text(f'<?xml version="1.0"?><gpx version="1.1" xmlns="http://www.topografix.com/GPX/1/1">'
                    f"<trk><trkseg>{points}</trkseg></trk></gpx>")
    trace = read_trace(path)
    assert trace.source_format == "gpx" and len(trace) == 3
    np.testing.assert_array_equal(trace.lat, LAT)
    np.testing.assert_array_equal(trace.alt, [10, 11, 12])
    np.testing.assert_allclose(trace.t, T0 + np.arange(3))
    assert not trace.has("speed")


def test_gpx_refuses_entities(tmp_path):
    path = tmp_path / "evil.gpx"
    path.write_text('<?xml version="1.0"?><!DOCTYPE gpx [<!ENTITY x "lol">]><gpx><wpt lat="1" lon="2"/></gpx>')
    with pytest.raises(InputError, match="evil.gpx"):
        read_trace(path)


def test_geojson_points_with_properties_and_linestring(tmp_path):
    features = [{"type": "Feature", "geometry": {"type": "Point", "coordinates": [lo, la, 5.0]},
                 "properties": {"time": f"2022-06-08T12:21:{46 + i}+00:00", "speed": 4.0, "heading": 90}}
                for i, (la, lo) in enumerate(zip(LAT, LON))]
    path = tmp_path / "points.geojson"
    path.write_text(json.dumps({"type": "FeatureCollection", "features": features}))
    trace = read_trace(path)
    np.testing.assert_allclose(trace.t, T0 + np.arange(3))
    np.testing.assert_array_equal(trace.speed, 4.0)
    np.testing.assert_array_equal(trace.alt, 5.0)
    line = tmp_path / "line.json"
    line.write_text(json.dumps({"type": "LineString", "coordinates": np.column_stack([LON, LAT]).tolist()}))
    trace = read_trace(line)
    assert trace.source_format == "geojson" and np.isnan(trace.t).all()
    np.testing.assert_array_equal(trace.lon, LON)


@pytest.mark.parametrize("text", [
    "lat,lon,time\n53.55,9.97,10\n53.5501,9.9702,11\n53.5502,9.9704,12\n",
    "Latitude;Longitude;Timestamp\n53.55;9.97;10\n53.5501;9.9702;11\n53.5502;9.9704;12\n",
    "53.55,9.97,10\n53.5501,9.9702,11\n53.5502,9.9704,12\n",
    "time\tlon\tlat\n10\t9.97\t53.55\n11\t9.9702\t53.5501\n12\t9.9704\t53.5502\n",
])
def test_csv_header_detection(tmp_path, text):
    path = tmp_path / "trace.csv"
    path.write_text(text)
    trace = read_trace(path)
    np.testing.assert_allclose(trace.lat, LAT)
    np.testing.assert_allclose(trace.lon, LON)
    np.testing.assert_allclose(trace.t, [10, 11, 12])


def test_csv_iso_times_and_bad_cell(tmp_path):
    path = tmp_path / "trace.csv"
    path.write_text("lat,lon,time\n53.55,9.97,2022-06-08T12:21:46Z\n")
    assert read_trace(path).t[0] == T0
    path.write_text("lat,lon\n53.55,9.97\n53.55,north\n")
    with pytest.raises(InputError) as error:
        read_trace(path)
    assert str(error.value) == f"{path}:3: column 'lon': 'north' is not a number"


def test_shared_ride_json(shared):
    path = shared("hamburg", "gnss_ride_b4", "thomas.json")
    trace = read_trace(path)
    raw = json.loads(path.read_text())
    assert trace.source_format == "ride-json" and len(trace) == len(raw) == 587
    assert trace.lat[0] == raw[0]["positionLat"] and trace.t[-1] == raw[-1]["timeUnixMillis"] / 1000
    assert np.all(np.diff(trace.t) > 0)
    assert 4.0 < float(np.median(trace.accuracy)) < 6.0   # README: median reported accuracy about 4.8 m


def test_shared_test_route_gpx_and_geojson_agree(shared):
    gpx = read_trace(shared("hamburg", "tavf_test_routes", "Teststrecke1_2_williy_brandt_strasse_routengeometrie.gpx"))
    geo = read_trace(shared("hamburg", "tavf_test_routes",
                            "Teststrecke1_2_williy_brandt_strasse_routengeometrie.geojson"))
    assert len(gpx) == len(geo) > 100
    np.testing.assert_allclose(gpx.lat, geo.lat, atol=1e-12)
    np.testing.assert_allclose(gpx.lon, geo.lon, atol=1e-12)


def test_local_heading_follows_the_georeference():
    from tavf_mapkit.opendrive.georef import GeoReference
    from tavf_mapkit.traces import Trace

    georef = GeoReference("+proj=tmerc +lat_0=53.55 +lon_0=9.97 +k=1 +x_0=0 +y_0=0 +ellps=WGS84 +units=m")
    trace = Trace.build([53.55, 53.55, 53.55], [9.97, 9.97, 9.97], "test", heading=[0.0, 90.0, np.nan])
    heading = trace.local_heading(georef)
    np.testing.assert_allclose(heading[:2], [np.pi / 2, 0.0], atol=1e-6)   # north is +y, east +x
    assert np.isnan(heading[2])


# ------------------------------------------------------------------ ROS bags (rosbags' writers, no ROS)

def _navsat_messages(store, ros1: bool):
    types = store.types
    Time = types["builtin_interfaces/msg/Time"]
    Header = types["std_msgs/msg/Header"]
    Status = types["sensor_msgs/msg/NavSatStatus"]
    Fix = types["sensor_msgs/msg/NavSatFix"]
    out = []
    for i, (la, lo) in enumerate(zip(LAT, LON)):
        stamp = Time(sec=int(T0) + i, nanosec=500_000_000)
        header = Header(seq=i, stamp=stamp, frame_id="gps") if ros1 else Header(stamp=stamp, frame_id="gps")
        covariance = np.array([4.0, 0, 0, 0, 9.0, 0, 0, 0, 1.0])
        out.append(Fix(header=header, status=Status(status=0, service=1), latitude=la, longitude=lo,
                       altitude=30.0 + i, position_covariance=covariance, position_covariance_type=2))
    # a "no fix" message must be dropped
    out.append(Fix(header=out[0].header, status=Status(status=-1, service=1), latitude=0.0, longitude=0.0,
                   altitude=0.0, position_covariance=np.zeros(9), position_covariance_type=0))
    return out


def test_ros2_bag_with_navsatfix(tmp_path):
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    folder = tmp_path / "ride_bag"
    with Writer(folder, version=9) as writer:
        connection = writer.add_connection("/gps/fix", "sensor_msgs/msg/NavSatFix", typestore=store)
        for i, message in enumerate(_navsat_messages(store, ros1=False)):
            writer.write(connection, int((T0 + i) * 1e9), store.serialize_cdr(message, "sensor_msgs/msg/NavSatFix"))
    trace = read_trace(folder)
    assert trace.source_format == "rosbag" and len(trace) == 3
    np.testing.assert_array_equal(trace.lat, LAT)
    np.testing.assert_allclose(trace.t, T0 + np.arange(3) + 0.5)
    np.testing.assert_allclose(trace.accuracy, np.sqrt(13.0))
    db3 = next(folder.glob("*.db3"))
    assert len(read_trace(db3)) == 3          # the storage file itself finds its metadata.yaml


def test_ros1_bag_with_navsatfix(tmp_path):
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    path = tmp_path / "ride.bag"
    with Writer(path) as writer:
        connection = writer.add_connection("/fix", "sensor_msgs/msg/NavSatFix", typestore=store)
        for i, message in enumerate(_navsat_messages(store, ros1=True)):
            writer.write(connection, int((T0 + i) * 1e9), store.serialize_ros1(message, "sensor_msgs/msg/NavSatFix"))
    trace = read_trace(path)
    np.testing.assert_array_equal(trace.lon, LON)
    np.testing.assert_array_equal(trace.alt, [30.0, 31.0, 32.0])


@pytest.mark.parametrize("version", ["ros1", "ros2"])
def test_bag_with_sbg_gps_pos(tmp_path, version):
    from rosbags.typesys import Stores, get_typestore

    from tavf_mapkit.traces.rosbag import SBG_GPS_POS, sbg_types

    store = get_typestore(Stores.ROS1_NOETIC if version == "ros1" else Stores.ROS2_HUMBLE)
    store.register(sbg_types())
    types = store.types
    Pos, Status = types[SBG_GPS_POS], types["sbg_driver/msg/SbgGpsPosStatus"]
    Time, Header, Vector3 = (types[name] for name in ("builtin_interfaces/msg/Time", "std_msgs/msg/Header",
                                                       "geometry_msgs/msg/Vector3"))
    messages = []
    for i, (la, lo) in enumerate(zip(LAT, LON)):
        stamp = Time(sec=int(T0) + i, nanosec=0)
        header = Header(seq=i, stamp=stamp, frame_id="sbg") if version == "ros1" else Header(stamp=stamp,
                                                                                               frame_id="sbg")
        status = Status(status=0, type=7, ifm=1, spoofing=1, osnma=1, gps_l1_used=True, gps_l2_used=True,
                        gps_l5_used=False, glo_l1_used=True, glo_l2_used=False)
        messages.append(Pos(header=header, time_stamp=i, status=status, gps_tow=i, latitude=la, longitude=lo,
                            altitude=12.0, undulation=40.0, position_accuracy=Vector3(x=0.03, y=0.04, z=0.1),
                            num_sv_tracked=20, num_sv_used=18, base_station_id=1, diff_age=5))
    if version == "ros1":
        from rosbags.rosbag1 import Writer

        path = tmp_path / "sbg.bag"
        with Writer(path) as writer:
            connection = writer.add_connection("/sbg/gps_pos", SBG_GPS_POS, typestore=store)
            for i, message in enumerate(messages):
                writer.write(connection, int((T0 + i) * 1e9), store.serialize_ros1(message, SBG_GPS_POS))
    else:
        from rosbags.rosbag2 import Writer

        path = tmp_path / "sbg_bag"
        with Writer(path, version=9) as writer:
            connection = writer.add_connection("/sbg/gps_pos", SBG_GPS_POS, typestore=store)
            for i, message in enumerate(messages):
                writer.write(connection, int((T0 + i) * 1e9), store.serialize_cdr(message, SBG_GPS_POS))
    trace = read_trace(path)
    np.testing.assert_array_equal(trace.lat, LAT)
    np.testing.assert_allclose(trace.t, T0 + np.arange(3))
    np.testing.assert_allclose(trace.accuracy, 0.05)


# ------------------------------------------------------------------ broken inputs

@pytest.mark.parametrize("name, content, message", [
    ("empty.csv", "", "the trace has no fixes (empty trace)"),
    ("header_only.csv", "lat,lon,time\n", "the trace has no fixes (empty trace)"),
    ("empty.json", "[]", "the trace has no fixes (empty trace)"),
    ("empty.geojson", '{"type": "FeatureCollection", "features": []}', "the trace has no fixes (empty trace)"),
    ("empty.gpx", '<gpx version="1.1"></gpx>', "the trace has no fixes (empty trace)"),
    ("broken.json", '{"type": ', "invalid JSON: Expecting value"),
    ("kml.gpx", "<kml/>", "expected a GPX document (<gpx>), found <kml>"),
    ("nolatlon.csv", "a,b\nx,y\n", ("no latitude/longitude columns in the header ['a', 'b'] (expected e.g. "
                                   "lat,lon,time)")),
    ("far.csv", "lat,lon\n123,9\n", "fix 1 is not a WGS84 position (lat 123, lon 9)"),
    ("binary.csv", b"\xff\xfe\x00\x01", "not a text file (expected GPX, GeoJSON, CSV or JSON)"),
    ("truncated.bag", b"#ROSBAG V2.0\n\x00\x01", "cannot read the bag"),
])
def test_bad_traces_fail_with_one_line_naming_the_file(tmp_path, name, content, message):
    path = tmp_path / name
    path.write_bytes(content if isinstance(content, bytes) else content.encode())
    with pytest.raises(InputError) as error:
        read_trace(path)
    text = str(error.value)
    assert text.startswith(str(path)) and message in text and "\n" not in text


def test_missing_file_and_bag_without_gnss(tmp_path):
    with pytest.raises(InputError, match="file not found"):
        read_trace(tmp_path / "nope.gpx")
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    folder = tmp_path / "imu_only"
    with Writer(folder, version=9) as writer:
        connection = writer.add_connection("/imu", "std_msgs/msg/String", typestore=store)
        writer.write(connection, 1, store.serialize_cdr(store.types["std_msgs/msg/String"](data="x"),
                                                        "std_msgs/msg/String"))
    with pytest.raises(InputError, match="no sensor_msgs/NavSatFix or sbg_driver/SbgGpsPos topic in the bag "
                                         r"\(types: std_msgs/msg/String\)"):
        read_trace(folder)
