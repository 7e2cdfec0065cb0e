"""The UDM HTTP service, served for real by uvicorn on a loopback port and asked over HTTP."""

from __future__ import annotations

import json
import random
import re
import subprocess
import sys
import time

import httpx
import numpy as np
import pytest
from pyproj import Geod

from twin.udm.model import EARTH_RADIUS_M, BBox
from twin.udm.server import MAX_BBOX_AREA_KM2, ServerThread, create_app
from twin.udm.store import SqliteRtreeStore

TOKEN = "test-token-1234"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
SPHERE = Geod(a=EARTH_RADIUS_M, b=EARTH_RADIUS_M)
HAMBURG = (53.55, 9.99)


def feature(object_id, lat, lon, layer=2, type_="traffic_sign", **properties):
    return {"type": "Feature", "id": object_id, "geometry": {"type": "Point", "coordinates": [lon, lat]},
            "properties": {"layer": layer, "type": type_, **properties}}


def collection(features):
    return {"type": "FeatureCollection", "features": features}


@pytest.fixture
def udm():
    """A fresh store behind a real server; yields (httpx client, store, server)."""
    store = SqliteRtreeStore()
    with (ServerThread(create_app(store, TOKEN)) as server,
          httpx.Client(base_url=server.url, trust_env=False, timeout=5.0) as http):
        yield http, store, server
    store.close()


@pytest.fixture(scope="module")
def fleet():
    """A server holding 1500 random objects posted over HTTP; yields (client, the posted features)."""
    rng = random.Random(3)
    now = time.time()
    features = []
    for index in range(1500):
        lat, lon = HAMBURG[0] + rng.uniform(-0.04, 0.04), HAMBURG[1] + rng.uniform(-0.06, 0.06)
        expired = rng.random() < 0.1
        features.append(feature(f"f{index}", lat, lon, layer=rng.randint(1, 4),
                                type_=rng.choice(["traffic_sign", "vehicle", "roadworks"]),
                                valid_until=(now - 60) if expired else None))
    store = SqliteRtreeStore()
    with (ServerThread(create_app(store, TOKEN)) as server,
          httpx.Client(base_url=server.url, trust_env=False, timeout=5.0) as http):
        reply = http.post("/objects", json=collection(features), headers=AUTH)
        assert reply.status_code == 201 and reply.json()["numberReturned"] == 1500
        yield http, features
    store.close()


def ids(reply):
    assert reply.status_code == 200, reply.text
    assert reply.headers["content-type"].startswith("application/geo+json")
    document = reply.json()
    assert document["type"] == "FeatureCollection"
    assert document["numberReturned"] == len(document["features"])
    for item in document["features"]:
        assert item["properties"]["id"] == item["id"]
    return [item["id"] for item in document["features"]]


def inside(box, item):
    lon, lat = item["geometry"]["coordinates"][:2]
    return box.contains(lat, lon)


def live(item):
    return item["properties"].get("valid_until") is None


def test_bbox_queries_match_brute_force(fleet):
    http, features = fleet
    rng = random.Random(5)
    for _ in range(40):
        lat, lon = HAMBURG[0] + rng.uniform(-0.04, 0.04), HAMBURG[1] + rng.uniform(-0.06, 0.06)
        half = rng.uniform(0.0005, 0.02)
        box = BBox(lon - half, lat - half, lon + half, lat + half)
        expected = {f["id"] for f in features if live(f) and inside(box, f)}
        got = ids(http.get("/objects", params={"bbox": box.as_param(), "limit": 10000}))
        assert len(got) == len(set(got)) and set(got) == expected


def test_radius_queries_match_geodesic_brute_force(fleet):
    http, features = fleet
    lons = np.array([f["geometry"]["coordinates"][0] for f in features])
    lats = np.array([f["geometry"]["coordinates"][1] for f in features])
    valid = np.array([live(f) for f in features])
    rng = random.Random(6)
    for _ in range(40):
        lat, lon = HAMBURG[0] + rng.uniform(-0.04, 0.04), HAMBURG[1] + rng.uniform(-0.06, 0.06)
        radius = rng.uniform(10.0, 1500.0)
        _, _, distances = SPHERE.inv(np.full_like(lons, lon), np.full_like(lats, lat), lons, lats)
        expected = {features[i]["id"] for i in np.flatnonzero((distances <= radius) & valid)}
        got = ids(http.get("/objects", params={"lat": lat, "lon": lon, "radius": radius, "limit": 10000}))
        assert set(got) == expected


def test_layer_and_type_filters(fleet):
    http, features = fleet
    box = BBox(9.95, 53.52, 10.03, 53.58)
    query = {"bbox": box.as_param(), "layers": "1,3", "types": "vehicle,roadworks", "limit": 10000}
    reply = http.get("/objects", params=query)
    expected = {f["id"] for f in features if live(f) and f["properties"]["layer"] in (1, 3)
                and f["properties"]["type"] in ("vehicle", "roadworks")
                and inside(box, f)}
    assert expected and set(ids(reply)) == expected
    for item in reply.json()["features"]:
        assert item["properties"]["layer"] in (1, 3)


def test_limit_truncates_and_says_so(fleet):
    http, _ = fleet
    document = http.get("/objects", params={"bbox": "9.9,53.5,10.1,53.6", "limit": 7}).json()
    assert document["numberReturned"] == 7 and document["truncated"] is True


@pytest.mark.parametrize("query", [
    {"bbox": "9.9,53.5,10.0"},                       # three numbers
    {"bbox": "9.9,53.5,10.0,abc"},
    {"bbox": "nan,53.5,10.0,53.6"},
    {"bbox": "9.9,53.5,inf,53.6"},
    {"bbox": "10.0,53.5,9.9,53.6"},                  # inverted longitude
    {"bbox": "9.9,53.6,10.0,53.5"},                  # inverted latitude
    {"bbox": "9.9,91,10.0,92"},
    {"bbox": "-10,40,10,60"},                        # far beyond the area limit
    {"bbox": "9.9,53.5,10.0,53.6", "layers": "5"},
    {"bbox": "9.9,53.5,10.0,53.6", "layers": "static"},
    {"bbox": "9.9,53.5,10.0,53.6", "types": "a,,b"},
    {"bbox": "9.9,53.5,10.0,53.6", "limit": "0"},
    {"bbox": "9.9,53.5,10.0,53.6", "layer": "2"},    # misspelt parameter
    {"bbox": "9.9,53.5,10.0,53.6", "lat": "53.55"},  # both kinds of query
    {"lat": "53.55", "lon": "9.99"},                 # radius missing
    {"lat": "NaN", "lon": "9.99", "radius": "10"},
    {"lat": "53.55", "lon": "9.99", "radius": "0"},
    {"lat": "53.55", "lon": "9.99", "radius": "1e9"},
    {},
])
def test_bad_queries_get_400_with_a_json_message(fleet, query):
    http, _ = fleet
    reply = http.get("/objects", params=query)
    assert reply.status_code == 400
    body = reply.json()
    assert body["error"] == "bad_request" and body["message"]


def test_area_limit_is_the_documented_one(fleet):
    http, _ = fleet
    side = 0.2  # ~ 22 km x 13 km at Hamburg: under the limit
    assert http.get("/objects", params={"bbox": f"9.9,53.5,{9.9 + side},{53.5 + side}"}).status_code == 200
    reply = http.get("/objects", params={"bbox": "9,53,10,54"})  # ~ 7400 km2
    assert reply.status_code == 400 and f"{MAX_BBOX_AREA_KM2:g} km2" in reply.json()["message"]


def test_writes_need_the_token(udm):
    http, store, _ = udm
    item = feature("sign-1", *HAMBURG)
    for headers in ({}, {"Authorization": "Bearer wrong"}, {"Authorization": TOKEN}):
        reply = http.post("/objects", json=item, headers=headers)
        assert reply.status_code == 401 and reply.json()["error"] == "unauthorized"
        assert reply.headers["www-authenticate"].startswith("Bearer")
    assert store.count() == 0
    assert http.post("/objects", json=item, headers=AUTH).status_code == 201
    assert http.delete("/objects/sign-1").status_code == 401
    assert http.delete("/objects/sign-1", headers={"Authorization": "Bearer wrong"}).status_code == 401
    assert store.count() == 1


def test_post_feature_then_collection_then_delete(udm):
    http, store, _ = udm
    reply = http.post("/objects", headers=AUTH, json=feature(
        "light-1", 53.5501, 9.9901, type_="traffic_signals", heading=90, extent={"height": 3.5},
        name="Rathausmarkt", source="test"))
    assert reply.status_code == 201 and reply.headers["location"] == "/objects/light-1"
    stored = reply.json()["properties"]
    assert stored["id"] == "light-1" and stored["created_at"].endswith("Z")
    assert stored["extent"] == {"height": 3.5}

    no_id = {"type": "Feature", "geometry": {"type": "Point", "coordinates": [9.9902, 53.5502]},
             "properties": {"layer": 4, "type": "vehicle", "class": "car"}}
    reply = http.post("/objects", headers=AUTH, json=collection([no_id, feature("cone-1", 53.5503, 9.9903, 3,
                                                                                "roadworks")]))
    assert reply.status_code == 201
    created = [item["id"] for item in reply.json()["features"]]
    assert created[1] == "cone-1" and re.fullmatch(r"[0-9a-f]{32}", created[0])  # the server named it

    near = ids(http.get("/objects", params={"lat": 53.5501, "lon": 9.9901, "radius": 100}))
    assert near[0] == "light-1" and set(near) == {"light-1", "cone-1", created[0]}  # nearest first
    assert http.get("/objects/light-1").json()["properties"]["name"] == "Rathausmarkt"

    assert http.delete("/objects/light-1", headers=AUTH).status_code == 204
    assert http.delete("/objects/light-1", headers=AUTH).status_code == 404
    assert http.get("/objects/light-1").status_code == 404
    assert "light-1" not in ids(http.get("/objects", params={"lat": 53.5501, "lon": 9.9901, "radius": 100}))
    assert store.count() == 2


@pytest.mark.parametrize("body, message", [
    (b"{not json", "not JSON"),
    (json.dumps({"type": "Point", "coordinates": [9.99, 53.55]}).encode(), "Feature or FeatureCollection"),
    (json.dumps(feature("x", 95.0, 9.99)).encode(), "latitude"),
    (json.dumps(feature("x", 53.55, 9.99, layer=7)).encode(), "layer"),
    (json.dumps(feature("bad/id", 53.55, 9.99)).encode(), "id"),
    (json.dumps(collection([feature("x", 53.55, 9.99), feature("x", 53.56, 9.99)])).encode(), "twice"),
    (json.dumps(collection([feature("ok", 53.55, 9.99), {"type": "Feature", "geometry": None,
                                                          "properties": {}}])).encode(), r"features\[1\]"),
])
def test_bad_posts_get_400_and_store_nothing(udm, body, message):
    http, store, _ = udm
    reply = http.post("/objects", content=body, headers={**AUTH, "Content-Type": "application/geo+json"})
    assert reply.status_code == 400 and re.search(message, reply.json()["message"])
    assert store.count() == 0


def test_expired_objects_are_never_returned_and_get_purged():
    store = SqliteRtreeStore()
    with (ServerThread(create_app(store, TOKEN, purge_interval_s=0.2)) as server,
          httpx.Client(base_url=server.url, trust_env=False) as http):
        now = time.time()
        reply = http.post("/objects", headers=AUTH, json=collection([
            feature("stale", *HAMBURG, layer=4, type_="vehicle", valid_until=now - 1),
            feature("brief", *HAMBURG, layer=4, type_="vehicle", valid_until=now + 0.5),
            feature("lasting", *HAMBURG, layer=4, type_="vehicle",
                    valid_until=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(now + 3600))),
        ]))
        assert reply.status_code == 201
        query = {"lat": HAMBURG[0], "lon": HAMBURG[1], "radius": 10}
        assert set(ids(http.get("/objects", params=query))) == {"brief", "lasting"}
        assert http.get("/objects/stale").status_code == 404
        time.sleep(0.6)
        assert ids(http.get("/objects", params=query)) == ["lasting"]
        deadline = time.monotonic() + 3.0
        while store.count() > 1 and time.monotonic() < deadline:  # the periodic purge has run
            time.sleep(0.05)
        assert store.count() == 1
    store.close()


def test_health_openapi_and_json_errors(udm):
    http, _, _ = udm
    assert http.get("/health").json() == {"status": "ok", "version": "0.1.0", "objects": 0}
    spec = http.get("/openapi.json").json()
    assert spec["openapi"].startswith("3.")
    assert {"get", "post"} <= set(spec["paths"]["/objects"])
    assert "delete" in spec["paths"]["/objects/{object_id}"]
    assert http.get("/nowhere").json()["error"] == "not_found"
    assert http.put("/objects").status_code == 405


def test_every_answer_says_the_servers_own_time(fleet):
    http, _ = fleet
    for query in ({"bbox": "9.9,53.5,10.1,53.6"}, {"bbox": "oops"}):
        started = time.perf_counter()
        reply = http.get("/objects", params=query)
        round_trip_ms = (time.perf_counter() - started) * 1000.0
        name, _, duration = reply.headers["server-timing"].partition(";dur=")
        assert name == "app"
        assert 0 < float(duration) < round_trip_ms  # inside the app: a part of what the client waited for
    assert reply.status_code == 400  # refusals are timed too


def test_oversized_body_gets_413(udm):
    http, _, _ = udm
    huge = b'{"type": "FeatureCollection", "features": [' + b" " * (17 * 1024 * 1024) + b"]}"
    reply = http.post("/objects", content=huge, headers=AUTH)
    assert reply.status_code == 413 and reply.json()["error"] == "too_large"


def write_tiny_build(folder):
    folder.mkdir()
    (folder / "map.osm").write_text(
        '<?xml version="1.0"?>\n<osm version="0.6">\n'
        '  <node id="1" lat="53.5500" lon="9.9900"><tag k="highway" v="traffic_signals"/></node>\n'
        '  <node id="2" lat="53.5501" lon="9.9901"><tag k="traffic_sign" v="DE:205"/></node>\n'
        '  <node id="3" lat="53.5502" lon="9.9902"><tag k="shop" v="bakery"/></node>\n'
        "</osm>\n", encoding="utf-8")
    return folder


def test_serve_command_seeds_a_build_and_answers(tmp_path):
    build = write_tiny_build(tmp_path / "build")
    db = tmp_path / "udm.sqlite"
    command = [sys.executable, "-m", "twin.cli.main", "udm", "serve", "--port", "0", "--map", str(build),
               "--db", str(db)]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               env={"TWIN_UDM_TOKEN": TOKEN, "PATH": "/usr/bin:/bin"})
    try:
        first = process.stdout.readline()
        url = re.search(r"http://127\.0\.0\.1:\d+", first).group(0)
        assert "objects=2" in first and "osm 2" in first
        deadline = time.monotonic() + 10.0
        while True:  # the URL is printed just before uvicorn starts accepting
            try:
                reply = httpx.get(f"{url}/objects", params={"bbox": "9.98,53.54,10.0,53.56"}, trust_env=False)
                break
            except httpx.ConnectError:
                assert time.monotonic() < deadline
                time.sleep(0.05)
        found = {item["id"]: item["properties"] for item in reply.json()["features"]}
        assert set(found) == {"osm-node-1", "osm-node-2"}
        assert found["osm-node-2"]["type"] == "traffic_sign" and found["osm-node-2"]["class"] == "DE:205"
        assert all(properties["layer"] == 2 for properties in found.values())
        reply = httpx.post(f"{url}/objects", json=feature("new", *HAMBURG), headers=AUTH, trust_env=False)
        assert reply.status_code == 201  # the token came from TWIN_UDM_TOKEN
    finally:
        process.terminate()
        process.wait(10)
    assert db.exists()


def test_serve_command_reports_a_missing_seed_folder_in_one_line(tmp_path):
    result = subprocess.run([sys.executable, "-m", "twin.cli.main", "udm", "serve", "--map",
                             str(tmp_path / "nope")], capture_output=True, text=True, timeout=30, check=False)
    assert result.returncode == 2
    assert result.stderr.strip().count("\n") == 0 and "does not exist" in result.stderr


def test_the_server_trusts_no_forwarded_headers():
    """uvicorn's proxy-header middleware would rewrite a request's client from X-Forwarded-For (for loopback
    peers) at a cost on every query; the UDM uses no client address, so it is left out."""
    from twin.udm.server import uvicorn_server

    server = uvicorn_server(create_app(SqliteRtreeStore(), "token"))
    server.config.load()
    assert server.config.proxy_headers is False
    assert "ProxyHeadersMiddleware" not in repr(server.config.loaded_app)
