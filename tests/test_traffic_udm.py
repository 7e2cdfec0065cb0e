"""SUMO traffic published to a real local UDM server and read back with the twin's own UDM client."""

from __future__ import annotations

import time

import numpy as np
import pytest
from pyproj import Geod

from twin.traffic.buildfiles import build_files
from twin.traffic.publish import TrafficPublishing, UdmPublisher, perceived_features, udm_id
from twin.traffic.publish_process import TrafficPublisherProcess
from twin.traffic.sumo import SumoTraffic, TrafficConfig, sumo_api
from twin.udm.client import UdmClient
from twin.udm.server import ServerThread, create_app
from twin.udm.store import SqliteRtreeStore

TOKEN = "traffic-test-token"
GEOD = Geod(ellps="WGS84")


@pytest.fixture
def udm_server():
    store = SqliteRtreeStore()
    with ServerThread(create_app(store, TOKEN)) as server:
        yield server
    store.close()


def distance_m(lon0, lat0, lon1, lat1):
    return GEOD.inv(lon0, lat0, lon1, lat1)[2]


@pytest.mark.slow
def test_bbox_queries_return_sumo_vehicles_where_sumo_has_them(jungfernstieg_build, udm_server):
    dt = 0.05
    every = 2  # 10 Hz publishing at the twin's 20 Hz step
    checked = matched_all = 0
    with SumoTraffic.from_build(jungfernstieg_build, TrafficConfig(vehicles=40, seed=7, step_s=dt)) as traffic, \
            UdmClient(udm_server.url, timeout_s=2.0, layers=(4,)) as client:
        publisher = UdmPublisher(udm_server.url, TOKEN)
        publishing = TrafficPublishing(publisher, traffic.frame, traffic.links, period_sim_s=every * dt)
        history = {}  # step -> {udm id: (lon, lat)} of SUMO's vehicles, box centres
        for _ in range(300):
            snapshot = traffic.step()
            actors = snapshot.actors
            centre = actors.centre
            lon, lat = traffic.frame.local_to_wgs84(centre[:, 0], centre[:, 1])
            history[snapshot.step] = {udm_id("sumo-vehicle-", a): (lo, la)
                                      for a, lo, la in zip(actors.ids, lon, lat)}
            # SUMO's own geo position of the front bumper (libsumo's projection, not ours) is half a length
            # ahead of the published centre for cars that are not inside a junction
            for i in np.flatnonzero(~actors.placed)[:5]:
                front_lon, front_lat = sumo_api.simulation.convertGeo(
                    *sumo_api.vehicle.getPosition(actors.ids[i]))
                assert distance_m(lon[i], lat[i], front_lon, front_lat) == pytest.approx(0.5 * actors.length[i],
                                                                                          abs=0.05)
            if snapshot.step % every:
                continue
            publishing.publish(snapshot)
            assert publisher.flush(5.0)
            # the ego's query: a 200 m square around some car
            probe = len(actors) // 2
            client.submit(float(lat[probe]), float(lon[probe]), side_m=200.0, frame=snapshot.step)
            assert client.flush(5.0)
            answers = client.poll()
            assert len(answers) == 1 and answers[0].ok, answers
            returned = {obj.id: obj for obj in answers[0].objects if obj.type == "vehicle"}
            # every SUMO car in the box now is returned, and nothing else
            box = [(a, p) for a, p in history[snapshot.step].items()
                   if distance_m(lon[probe], lat[probe], p[0], lat[probe]) < 99.0
                   and distance_m(lon[probe], lat[probe], lon[probe], p[1]) < 99.0]
            assert {a for a, _ in box} <= set(returned)
            for object_id, obj in returned.items():
                # age <= 2 steps: the object matches SUMO's position of this step or one of the two before
                best = min(distance_m(obj.lon, obj.lat, *history[k][object_id])
                           for k in range(snapshot.step - 2, snapshot.step + 1)
                           if object_id in history.get(k, {}))
                assert best <= 0.5
                checked += 1
            matched_all += 1
        publisher.close()
        assert not publisher.stats.errors, publisher.stats.errors
    assert matched_all == 150 and checked > 300


def test_signal_phases_and_departed_vehicles(sample_build_dir, udm_server):
    import httpx

    with SumoTraffic.from_build(sample_build_dir, TrafficConfig(vehicles=8, seed=2)) as traffic, \
            httpx.Client(base_url=udm_server.url, trust_env=False) as http:
        publisher = UdmPublisher(udm_server.url, TOKEN)
        publishing = TrafficPublishing(publisher, traffic.frame, traffic.links, period_sim_s=0.1)
        assert len(traffic.links) > 0  # the sample has one signalised junction
        west, south, east, north = 9.96, 53.55, 9.99, 53.56
        seen_states = set()
        departed_checked = False
        previous_ids = set()
        for _ in range(1600):
            snapshot = traffic.step()
            if snapshot.step % 2:
                continue
            publishing.publish(snapshot)
            assert publisher.flush(5.0)
            if snapshot.step % 40:
                continue
            reply = http.get("/objects", params={"bbox": f"{west},{south},{east},{north}", "layers": "3"})
            signals = reply.json()["features"]
            assert len(signals) == len(traffic.links)
            by_id = {f["id"]: f["properties"]["class"] for f in signals}
            for row in range(len(traffic.links)):
                object_id = udm_id("sumo-signal-", f"{traffic.links.tls_id[row]}:{traffic.links.link_index[row]}:"
                                   f"{traffic.links.in_lane[row]}:{traffic.links.out_lane[row]}")
                assert by_id[object_id] == {"r": "red", "y": "yellow", "G": "green", "g": "green_minor",
                                            "s": "green_stop", "u": "red_yellow"}[snapshot.signal_state[row]]
            seen_states |= set(by_id.values())
            ids = {f["id"] for f in http.get("/objects", params={"bbox": f"{west},{south},{east},{north}",
                                                                  "layers": "4"}).json()["features"]}
            assert ids == {udm_id("sumo-vehicle-", a) for a in snapshot.actors.ids}
            departed_checked |= bool(previous_ids - ids)  # some car left SUMO and is gone from the UDM
            previous_ids = ids
        publisher.close()
    assert {"red", "green"} <= seen_states
    assert departed_checked


def test_publisher_process_posts_the_newest_snapshot(sample_build_dir, udm_server):
    """The child-process publisher: snapshots within the wall interval are held, the newest one wins."""
    import httpx

    files = build_files(sample_build_dir)
    bbox = {"bbox": "9.96,53.55,9.99,53.56", "layers": "4"}
    with SumoTraffic.from_build(sample_build_dir, TrafficConfig(vehicles=8, seed=2)) as traffic, \
            httpx.Client(base_url=udm_server.url, trust_env=False) as http:
        publisher = TrafficPublisherProcess(udm_server.url, TOKEN, files.net, files.xodr, traffic.links,
                                            period_sim_s=0.1, min_interval_s=60.0)
        for _ in range(400):
            snapshot = traffic.step()
            if snapshot.step % 2 == 0:
                publisher.publish(snapshot)
        # the first went at once; each later one replaced the one held before it
        assert publisher.sent == 1 and publisher.held == 198
        assert publisher.flush(5.0)  # sends the newest held snapshot
        stats = publisher.stats
        assert publisher.sent == 2 and stats.batches == 2 and 1 <= stats.posts <= 2 and not stats.errors
        features = http.get("/objects", params=bbox).json()["features"]
        centre = snapshot.actors.centre
        lon, lat = traffic.frame.local_to_wgs84(centre[:, 0], centre[:, 1])
        where = {udm_id("sumo-vehicle-", a): (lo, la) for a, lo, la in zip(snapshot.actors.ids, lon, lat)}
        assert {f["id"] for f in features} == set(where) and len(where) > 0
        for feature in features:
            assert distance_m(*feature["geometry"]["coordinates"], *where[feature["id"]]) < 0.01
        publisher.close()
        assert not publisher.publish(snapshot)  # closed: refused, not raised


def test_publisher_survives_an_unreachable_udm():
    publisher = UdmPublisher("http://127.0.0.1:9", TOKEN, timeout_s=0.2)  # port 9 (discard): nobody listens
    publisher.publish([{"type": "Feature", "id": "a", "geometry": {"type": "Point", "coordinates": [10, 53]},
                        "properties": {"layer": 4, "type": "vehicle"}}])
    assert publisher.flush(5.0)
    assert sum(publisher.stats.errors.values()) == 1 and publisher.stats.posts == 0
    publisher.close()


def test_wrong_token_is_counted(udm_server):
    publisher = UdmPublisher(udm_server.url, "wrong")
    publisher.publish([{"type": "Feature", "id": "a", "geometry": {"type": "Point", "coordinates": [10, 53]},
                        "properties": {"layer": 4, "type": "vehicle"}}])
    assert publisher.flush(5.0)
    assert publisher.stats.errors == {"http_401": 1}
    publisher.close()


def test_perception_is_ground_truth_within_range_plus_noise(sample_build_dir):
    with SumoTraffic.from_build(sample_build_dir, TrafficConfig(vehicles=8, seed=2)) as traffic:
        for _ in range(100):
            snapshot = traffic.step()
        centre = snapshot.actors.centre
        ego = (float(centre[0, 0]), float(centre[0, 1]))
        exact = perceived_features(snapshot, traffic.frame, ego, 80.0, 0.0, np.random.default_rng(0), time.time())
        inside = np.hypot(centre[:, 0] - ego[0], centre[:, 1] - ego[1]) <= 80.0
        assert len(exact) == int(inside.sum()) >= 1
        noisy = perceived_features(snapshot, traffic.frame, ego, 80.0, 1.0, np.random.default_rng(0), time.time())
        errors = [distance_m(*a["geometry"]["coordinates"], *b["geometry"]["coordinates"]) for a, b in zip(exact, noisy)]
        assert 0.0 < np.mean(errors) < 4.0


def test_udm_ids_are_valid_and_distinct():
    assert udm_id("sumo-vehicle-", "t12") == "sumo-vehicle-t12"
    a, b = udm_id("x-", "a b"), udm_id("x-", "a/b")
    assert a != b and a.startswith("x-a_b~") and b.startswith("x-a_b~")
