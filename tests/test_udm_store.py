"""The SQLite R*Tree store and the build-folder seeders, checked against brute force on random objects."""

from __future__ import annotations

import json
import math
import random
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pyproj import Geod

from tavf_mapkit.errors import InputError
from twin.udm.model import (
    EARTH_RADIUS_M,
    BBox,
    Extent,
    InvalidObject,
    UdmObject,
    boxes_around,
    haversine_m,
)
from twin.udm.seed import SEED_SOURCES, SeedSource, seed_from_build
from twin.udm.store import SqliteRtreeStore, Store

# An independent distance: pyproj's geodesic on a sphere of the same radius (not our haversine).
SPHERE = Geod(a=EARTH_RADIUS_M, b=EARTH_RADIUS_M)
HAMBURG = (53.55, 9.99)
TYPES = ("traffic_signals", "traffic_sign", "vehicle", "roadworks")


def random_objects(rng: random.Random, count: int, now: float, spread_deg: float = 0.05) -> list[UdmObject]:
    objects = []
    for index in range(count):
        expired = rng.random() < 0.1
        objects.append(UdmObject(
            id=f"obj-{index}",
            layer=rng.randint(1, 4),
            type=rng.choice(TYPES),
            lat=HAMBURG[0] + rng.uniform(-spread_deg, spread_deg),
            lon=HAMBURG[1] + rng.uniform(-spread_deg, spread_deg),
            valid_until=now - 10.0 if expired else (now + 3600.0 if rng.random() < 0.5 else None),
        ))
    return objects


@pytest.fixture(scope="module")
def filled():
    now = time.time()
    objects = random_objects(random.Random(7), 3000, now)
    store = SqliteRtreeStore()
    store.upsert(objects, now=now)
    yield store, objects, now
    store.close()


def test_sqlite_store_satisfies_the_store_protocol():
    assert isinstance(SqliteRtreeStore(), Store)


def test_bbox_query_matches_brute_force(filled):
    store, objects, now = filled
    rng = random.Random(11)
    for _ in range(200):
        # Box edges are sometimes an object's exact coordinates, to pin down that edges are inclusive.
        a, b = rng.sample(objects, 2)
        if rng.random() < 0.5:
            lats, lons = sorted((a.lat, b.lat)), sorted((a.lon, b.lon))
        else:
            lat, lon = HAMBURG[0] + rng.uniform(-0.05, 0.05), HAMBURG[1] + rng.uniform(-0.05, 0.05)
            half = rng.uniform(0.0, 0.02)
            lats, lons = [lat - half, lat + half], [lon - half, lon + half]
        box = BBox(lons[0], lats[0], lons[1], lats[1])
        expected = {o.id for o in objects if box.contains(o.lat, o.lon) and o.is_valid_at(now)}
        got = [o.id for o in store.in_bbox(box, now=now, limit=10_000)]
        assert len(got) == len(set(got))
        assert set(got) == expected


def test_radius_query_matches_geodesic_brute_force_and_is_nearest_first(filled):
    store, objects, now = filled
    lats = np.array([o.lat for o in objects])
    lons = np.array([o.lon for o in objects])
    valid = np.array([o.is_valid_at(now) for o in objects])
    rng = random.Random(12)
    for _ in range(100):
        lat, lon = HAMBURG[0] + rng.uniform(-0.05, 0.05), HAMBURG[1] + rng.uniform(-0.05, 0.05)
        radius = rng.uniform(1.0, 2000.0)
        _, _, distances = SPHERE.inv(np.full_like(lons, lon), np.full_like(lats, lat), lons, lats)
        # Objects within a micrometre of the rim could go either way by rounding; leave them out.
        ambiguous = {objects[i].id for i in np.flatnonzero(np.abs(distances - radius) < 1e-6)}
        expected = {objects[i].id for i in np.flatnonzero((distances <= radius) & valid)} - ambiguous
        found = store.within_radius(lat, lon, radius, now=now, limit=10_000)
        assert {o.id for o in found} - ambiguous == expected
        ranges = [haversine_m(lat, lon, o.lat, o.lon) for o in found]
        assert ranges == sorted(ranges)


def test_radius_limit_keeps_the_nearest(filled):
    store, _, now = filled
    everything = store.within_radius(*HAMBURG, 3000.0, now=now, limit=10_000)
    nearest = store.within_radius(*HAMBURG, 3000.0, now=now, limit=5)
    assert [o.id for o in nearest] == [o.id for o in everything[:5]]


def test_layer_and_type_filters(filled):
    store, objects, now = filled
    box = BBox(HAMBURG[1] - 0.03, HAMBURG[0] - 0.03, HAMBURG[1] + 0.03, HAMBURG[0] + 0.03)
    got = store.in_bbox(box, layers=[2, 4], types=["vehicle", "roadworks"], now=now, limit=10_000)
    expected = {
        o.id for o in objects
        if box.contains(o.lat, o.lon) and o.is_valid_at(now) and o.layer in (2, 4)
        and o.type in ("vehicle", "roadworks")
    }
    assert expected and {o.id for o in got} == expected


def test_expired_objects_are_hidden_then_purged():
    store = SqliteRtreeStore()
    now = 1_000_000.0
    store.upsert([
        UdmObject(id="old", layer=4, type="vehicle", lat=53.55, lon=9.99, valid_until=now - 1.0),
        UdmObject(id="edge", layer=4, type="vehicle", lat=53.55, lon=9.99, valid_until=now),
        UdmObject(id="fresh", layer=4, type="vehicle", lat=53.55, lon=9.99, valid_until=now + 1.0),
        UdmObject(id="forever", layer=1, type="sign", lat=53.55, lon=9.99),
    ], now=now - 5.0)
    box = BBox(9.98, 53.54, 10.0, 53.56)
    assert {o.id for o in store.in_bbox(box, now=now)} == {"fresh", "forever"}
    assert store.get("old", now=now) is None
    assert store.purge_expired(now=now) == 2
    assert store.count() == 2
    assert {o.id for o in store.in_bbox(box, now=now + 2.0)} == {"forever"}
    assert store.purge_expired(now=now + 2.0) == 1
    assert store.count() == 1


def test_upsert_moves_the_index_entry_and_keeps_creation_time():
    store = SqliteRtreeStore()
    store.upsert([UdmObject(id="car", layer=4, type="vehicle", lat=53.55, lon=9.99)], now=100.0)
    moved = store.upsert([UdmObject(id="car", layer=4, type="vehicle", lat=53.60, lon=10.05,
                                    extent=Extent(4.5, 1.8, 1.5))], now=200.0)
    assert (moved[0].created_at, moved[0].updated_at) == (100.0, 200.0)
    assert store.in_bbox(BBox(9.98, 53.54, 10.0, 53.56), now=200.0) == []
    (found,) = store.in_bbox(BBox(10.04, 53.59, 10.06, 53.61), now=200.0)
    assert found.extent == Extent(4.5, 1.8, 1.5) and found.created_at == 100.0
    assert store.count() == 1


def test_delete_removes_from_table_and_index():
    store = SqliteRtreeStore()
    store.upsert([UdmObject(id="a", layer=2, type="sign", lat=53.55, lon=9.99)])
    assert store.delete("a") is True
    assert store.delete("a") is False
    assert store.in_bbox(BBox(9.98, 53.54, 10.0, 53.56)) == []
    assert store.count() == 0


def test_file_store_keeps_objects_across_reopen(tmp_path):
    path = tmp_path / "udm.sqlite"
    store = SqliteRtreeStore(path)
    store.upsert([UdmObject(id="a", layer=2, type="sign", lat=53.55, lon=9.99, name="Stop")])
    store.close()
    reopened = SqliteRtreeStore(path)
    (found,) = reopened.in_bbox(BBox(9.98, 53.54, 10.0, 53.56))
    assert (found.id, found.name) == ("a", "Stop")
    reopened.close()


@settings(max_examples=300, deadline=None)
@given(
    lat=st.floats(-89.9, 89.9),
    lon=st.floats(-180.0, 180.0),
    radius=st.floats(1.0, 20_000.0),
    azimuth=st.floats(-180.0, 180.0),
    fraction=st.floats(0.0, 0.999),
)
def test_circle_boxes_cover_every_point_of_the_circle(lat, lon, radius, azimuth, fraction):
    # Includes circles over the poles and across the antimeridian.
    point_lon, point_lat, _ = SPHERE.fwd(lon, lat, azimuth, radius * fraction)
    assert any(box.contains(point_lat, point_lon) for box in boxes_around(lat, lon, radius))


def test_feature_round_trip_and_validation():
    obj = UdmObject(id="x1", layer=3, type="roadworks", object_class="lane_closed", name="A7", lat=53.5,
                    lon=9.9, alt=12.0, heading=370.0 % 360.0, extent=Extent(20.0, 3.5, None),
                    valid_until=2_000_000_000.0, source="test", created_at=1.5, updated_at=2.5)
    back = UdmObject.from_feature(json.loads(json.dumps(obj.to_feature())))
    assert back == obj and back.created_at == 1.5
    with pytest.raises(InvalidObject, match="layer"):
        UdmObject.from_feature({**obj.to_feature(), "properties": {"type": "x", "layer": 5}})
    with pytest.raises(InvalidObject, match="latitude"):
        UdmObject.from_feature({**obj.to_feature(), "geometry": {"type": "Point", "coordinates": [9.9, 91]}})
    with pytest.raises(InvalidObject, match="time zone"):
        UdmObject.from_feature({**obj.to_feature(), "properties": {"type": "x", "layer": 1,
                                                                   "valid_until": "2030-01-01T00:00:00"}})
    assert math.isclose(UdmObject.from_feature({**obj.to_feature(), "properties": {
        "type": "x", "layer": 1, "heading": -90}}).heading, 270.0)


# --- seeding from a build folder --------------------------------------------------------------------------

OSM = """<?xml version="1.0" encoding="UTF-8"?>
<osm version="0.6" generator="test">
  <node id="101" lat="53.5501" lon="9.9901">
    <tag k="highway" v="traffic_signals"/><tag k="traffic_signals" v="signal"/><tag k="crossing" v="marked"/>
  </node>
  <node id="102" lat="53.5502" lon="9.9902">
    <tag k="traffic_sign" v="DE:206"/><tag k="direction" v="NE"/>
  </node>
  <node id="103" lat="53.5503" lon="9.9903"><tag k="highway" v="stop"/><tag k="direction" v="270"/></node>
  <node id="104" lat="53.5504" lon="9.9904"><tag k="highway" v="give_way"/></node>
  <node id="105" lat="53.5505" lon="9.9905">
    <tag k="highway" v="crossing"/><tag k="crossing" v="zebra"/>
  </node>
  <node id="106" lat="53.5506" lon="9.9906"><tag k="highway" v="bus_stop"/><tag k="name" v="Rathaus"/></node>
  <node id="107" lat="53.5507" lon="9.9907"><tag k="amenity" v="bench"/></node>
  <node id="108" lat="53.5508" lon="9.9908"/>
  <way id="1"><nd ref="101"/><nd ref="102"/><tag k="highway" v="residential"/></way>
</osm>
"""

SIGNALS = {
    "type": "FeatureCollection",
    "features": [
        {"type": "Feature", "geometry": {"type": "Point", "coordinates": [9.991, 53.551]},
         "properties": {"type": "traffic_light", "name": "Main St / 1st Ave", "heading": 90}},
        {"type": "Feature", "id": "sig-7", "geometry": {"type": "Point", "coordinates": [9.992, 53.552]},
         "properties": {"type": "traffic_sign", "class": "DE:274-50", "heading": 180}},
    ],
}


def write_build(folder, signals=SIGNALS):
    (folder / "osm").mkdir(parents=True)
    (folder / "osm" / "extract.osm").write_text(OSM, encoding="utf-8")
    if signals is not None:
        (folder / "signals.geojson").write_text(json.dumps(signals), encoding="utf-8")
    return folder


def test_seed_from_build_reads_osm_nodes_and_signals_geojson(tmp_path):
    store = SqliteRtreeStore()
    counts = seed_from_build(store, write_build(tmp_path / "build"))
    assert counts == {"osm": 5, "signals.geojson": 2, "opendrive": 0}
    objects = {o.id: o for o in store.in_bbox(BBox(9.98, 53.54, 10.0, 53.56))}
    assert set(objects) == {"osm-node-101", "osm-node-102", "osm-node-103", "osm-node-104", "osm-node-105",
                            "signals-0", "sig-7"}
    assert all(o.layer == 2 and o.valid_until is None for o in objects.values())
    signal = objects["osm-node-101"]
    assert (signal.type, signal.object_class, signal.lat, signal.lon) == ("traffic_signals", "signal",
                                                                           53.5501, 9.9901)
    assert (objects["osm-node-102"].type, objects["osm-node-102"].object_class) == ("traffic_sign", "DE:206")
    assert objects["osm-node-102"].heading == 45.0
    assert (objects["osm-node-103"].type, objects["osm-node-103"].heading) == ("stop", 270.0)
    assert objects["osm-node-104"].type == "give_way"
    assert (objects["osm-node-105"].type, objects["osm-node-105"].object_class) == ("crossing", "zebra")
    assert objects["osm-node-101"].source == "osm:extract.osm"
    assert (objects["signals-0"].name, objects["signals-0"].heading) == ("Main St / 1st Ave", 90.0)
    assert objects["sig-7"].source == "signals.geojson"


def test_seeding_twice_replaces_rather_than_duplicates(tmp_path):
    store = SqliteRtreeStore()
    build = write_build(tmp_path / "build", signals=None)
    assert seed_from_build(store, build) == {"osm": 5, "signals.geojson": 0, "opendrive": 0}
    seed_from_build(store, build)
    assert store.count() == 5


def test_seed_sources_are_pluggable(tmp_path):
    store = SqliteRtreeStore()
    signal = UdmObject(id="xodr-signal-1", layer=2, type="traffic_light", lat=53.55, lon=9.99)
    extra = SeedSource("opendrive", lambda build: [signal])
    counts = seed_from_build(store, write_build(tmp_path / "b"), sources=[*SEED_SOURCES, extra])
    assert counts["opendrive"] == 1 and store.get("xodr-signal-1") is not None


def test_bad_seed_inputs_raise_input_errors(tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        seed_from_build(SqliteRtreeStore(), tmp_path / "missing")
    bad_geojson = tmp_path / "bad"
    bad_geojson.mkdir()
    bad_point = {"type": "Feature", "geometry": {"type": "Point", "coordinates": [9, 95]},
                 "properties": {"type": "x"}}
    signals = {"type": "FeatureCollection", "features": [bad_point]}
    (bad_geojson / "signals.geojson").write_text(json.dumps(signals))
    with pytest.raises(InputError, match=r"features\[0\]: latitude"):
        seed_from_build(SqliteRtreeStore(), bad_geojson)
    bad_osm = tmp_path / "bad_osm"
    bad_osm.mkdir()
    (bad_osm / "broken.osm").write_text("<osm><node id='1' lat=")
    with pytest.raises(InputError, match="broken.osm"):
        seed_from_build(SqliteRtreeStore(), bad_osm)
