"""Seeding the UDM from a build's OpenDRIVE signals and objects: positions, headings, ids, real builds."""

from __future__ import annotations

import math
from pathlib import Path

import httpx
import numpy as np
import pyproj
import pytest
from click.testing import CliRunner
from lxml import etree

from tavf_mapkit.cli.main import cli as mapkit
from tavf_mapkit.errors import InputError
from tests.xodr_factory import document, road_xml
from twin.udm.model import BBox, haversine_m
from twin.udm.seed import SEED_SOURCES, objects_from_osm_files, seed_from_build
from twin.udm.seed_opendrive import compass_bearing, objects_from_opendrive, safe_id
from twin.udm.server import ServerThread, create_app
from twin.udm.store import SqliteRtreeStore

PROJ = "+proj=tmerc +lat_0=53.55 +lon_0=9.99 +k=1 +x_0=0 +y_0=0 +ellps=WGS84 +units=m +no_defs"
SAMPLE_OSM = Path(__file__).resolve().parents[1] / "sample_data" / "tavf_synthetic.osm"
EVERYWHERE = BBox(-180.0, -90.0, 180.0, 90.0)

SIGNALS = """
  <signals>
    <signal id="ahead" s="50" t="-2" orientation="+" dynamic="no" zOffset="2" country="DE" type="206"
            subtype="-1" width="0.6" height="0.6"/>
    <signal id="back" s="50" t="2" orientation="-" dynamic="yes" zOffset="5" country="OpenDRIVE"
            type="1000001" subtype="-1"/>
    <signal id="turned" s="20" t="-2" orientation="+" hOffset="1.5707963267948966" dynamic="no"
            country="DE" type="274" subtype="-1" value="30" unit="km/h"/>
  </signals>
  <objects>
    <object id="cw#1" type="crosswalk" s="80" t="0" hdg="0" length="4" width="8"/>
  </objects>"""


def write_xodr_build(folder, extra=SIGNALS, georeference=True):
    folder.mkdir()
    header = f"<geoReference><![CDATA[{PROJ}]]></geoReference>" if georeference else ""
    # A straight road heading east from the projection origin.
    geometry = '<geometry s="0" x="0" y="0" hdg="0" length="100"><line/></geometry>'
    (folder / "map.xodr").write_text(document(road_xml(geometry, 100.0, extra=extra, road_id="r1"),
                                              header_extra=header), encoding="utf-8")
    return folder


def local_to_wgs84(x, y):
    return pyproj.Transformer.from_crs(pyproj.CRS(PROJ), "EPSG:4326", always_xy=True).transform(x, y)


def angle_difference(a, b):
    return abs((a - b + 180.0) % 360.0 - 180.0)


def test_signals_sit_on_the_road_and_face_their_direction_of_travel(tmp_path):
    build = write_xodr_build(tmp_path / "b")
    objects = {o.id: o for o in objects_from_opendrive(build)}
    assert set(objects) == {"xodr-signal-ahead", "xodr-signal-back", "xodr-signal-turned",
                            "xodr-object-r1-cw~231"}
    expected = {"xodr-signal-ahead": (50, -2, 90.0), "xodr-signal-back": (50, 2, 270.0),
                "xodr-signal-turned": (20, -2, 0.0), "xodr-object-r1-cw~231": (80, 0, 90.0)}
    for object_id, (x, y, heading) in expected.items():
        lon, lat = local_to_wgs84(x, y)
        assert haversine_m(lat, lon, objects[object_id].lat, objects[object_id].lon) < 1e-3
        # The meridian convergence of a tmerc this close to its central meridian is far below 0.01 deg.
        assert angle_difference(objects[object_id].heading, heading) < 0.01, object_id

    ahead, back, turned = objects["xodr-signal-ahead"], objects["xodr-signal-back"], objects["xodr-signal-turned"]
    assert (ahead.type, ahead.object_class, ahead.layer) == ("traffic_sign", "DE:206", 2)
    assert (ahead.extent.width, ahead.extent.height) == (0.6, 0.6)
    assert (back.type, back.object_class) == ("traffic_signals", "OpenDRIVE:1000001")
    assert turned.object_class == "DE:274=30km/h"
    crossing = objects["xodr-object-r1-cw~231"]
    assert (crossing.type, crossing.object_class, crossing.extent.length) == ("crossing", "crosswalk", 4.0)
    assert all(o.source == "xodr:map.xodr" and o.valid_until is None for o in objects.values())


def test_opendrive_is_a_seed_source_and_a_map_without_georeference_is_refused(tmp_path):
    assert "opendrive" in [source.name for source in SEED_SOURCES]
    counts = seed_from_build(SqliteRtreeStore(), write_xodr_build(tmp_path / "b"))
    assert counts["opendrive"] == 4
    with pytest.raises(InputError, match="no geoReference") as error:
        list(objects_from_opendrive(write_xodr_build(tmp_path / "c", georeference=False)))
    assert "map.xodr" in str(error.value)
    # no signals and no georeference is fine: there is nothing to place
    assert list(objects_from_opendrive(write_xodr_build(tmp_path / "d", extra="", georeference=False))) == []


def test_safe_ids_keep_the_id_alphabet_and_stay_distinct():
    assert safe_id("xodr-signal-12_0") == "xodr-signal-12_0"
    assert safe_id("a#b") != safe_id("a~23b") and safe_id("a#b") == "a~23b"
    long = safe_id("x" * 300)
    assert len(long) <= 128 and long != safe_id("x" * 299)


def test_compass_bearing_cardinal_directions():
    bearings = compass_bearing([0, 0, 0, 0], [0, 0, 0, 0], [1, 0, -1, 0], [0, 1, 0, -1])
    np.testing.assert_allclose(bearings, [0.0, 90.0, 180.0, 270.0], atol=1e-9)


def count_signals(xodr):
    return sum(1 for _ in etree.parse(str(xodr)).iter("signal"))


def test_sample_build_signals_stand_at_the_osm_signal_junction_facing_it(sample_build_dir):
    """Independent reference: netconvert turns OSM traffic_signals nodes into OpenDRIVE signals on the roads
    entering that junction, so every seeded signal must be a few metres from an OSM signal node and face it."""
    signals = [o for o in objects_from_opendrive(sample_build_dir) if o.id.startswith("xodr-signal-")]
    assert len(signals) == count_signals(sample_build_dir / "sample.xodr") > 0
    nodes = [o for o in objects_from_osm_files(sample_build_dir) if o.type == "traffic_signals"]
    assert nodes
    for signal in signals:
        assert signal.type == "traffic_signals"
        distances = [haversine_m(signal.lat, signal.lon, node.lat, node.lon) for node in nodes]
        nearest = nodes[int(np.argmin(distances))]
        assert min(distances) < 20.0, signal.id
        towards = float(compass_bearing(signal.lat, signal.lon, nearest.lat, nearest.lon))
        assert angle_difference(towards, signal.heading) < 30.0, signal.id


def test_seeded_sample_build_answers_signal_queries_over_http(sample_build_dir):
    store = SqliteRtreeStore()
    counts = seed_from_build(store, sample_build_dir)
    assert counts["opendrive"] == count_signals(sample_build_dir / "sample.xodr")
    signal = next(o for o in store.in_bbox(EVERYWHERE) if o.id.startswith("xodr-signal-"))
    with ServerThread(create_app(store, "t")) as server:
        reply = httpx.get(f"{server.url}/objects", trust_env=False,
                          params={"lat": signal.lat, "lon": signal.lon, "radius": 1.0, "types": "traffic_signals"})
    assert reply.status_code == 200
    found = {feature["id"]: feature["properties"] for feature in reply.json()["features"]}
    assert signal.id in found and found[signal.id]["source"] == "xodr:sample.xodr"
    assert math.isclose(found[signal.id]["heading"], signal.heading)
    store.close()


@pytest.mark.slow
def test_full_profile_build_seeds_crosswalks_and_signals(tmp_path):
    """With the full netconvert profile the xodr carries guessed crosswalks (<object type=crosswalk>)."""
    out = tmp_path / "sample-full"
    result = CliRunner().invoke(mapkit, ["build", str(SAMPLE_OSM), "-o", str(out),
                                         "--profile", "full", "-q"], catch_exceptions=False)
    assert result.exit_code == 0, result.output
    xodr = out / "sample-full.xodr"
    tree = etree.parse(str(xodr))
    crosswalks = sum(1 for element in tree.iter("object") if element.get("type") == "crosswalk")
    store = SqliteRtreeStore()
    counts = seed_from_build(store, out)
    assert counts["opendrive"] == crosswalks + count_signals(xodr)
    assert crosswalks > 0
    seeded = [o for o in store.in_bbox(EVERYWHERE) if o.id.startswith("xodr-object-")]
    assert len(seeded) == crosswalks and all(o.type == "crossing" for o in seeded)
