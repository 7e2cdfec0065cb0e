"""mapkit view's data, served by its real app (starlette's TestClient): the map has one lane feature per lane
of the build, findings carry rule/road/lane/s and stand on their lane, the scene lists the build's tiles, a
run replays the ego exactly as trajectory.csv has it; bad input and a taken port are one-line errors."""

from __future__ import annotations

import csv
import json
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import shapely
from click.testing import CliRunner

from tavf_mapkit.cli.main import cli

TWIN = str(Path(sys.executable).parent / "twin")


@pytest.fixture(scope="module")
def sample_run(sample_build_dir, tmp_path_factory) -> Path:
    """A short real drive on the sample build with SUMO vehicles and pedestrians, asking a local UDM seeded
    with the build's objects."""
    from twin.udm.seed import seed_from_build
    from twin.udm.server import ServerThread, create_app
    from twin.udm.store import SqliteRtreeStore

    out = tmp_path_factory.mktemp("view-run") / "run"
    store = SqliteRtreeStore()
    seed_from_build(store, sample_build_dir)
    with ServerThread(create_app(store, "token")) as server:
        subprocess.run([TWIN, "drive", "--map", str(sample_build_dir), "--random", "--duration", "6", "--seed",
                        "1", "--traffic", "4", "--pedestrians", "2", "--udm", server.url, "--udm-bbox", "400",
                        "--no-plot", "-o", str(out)], check=True, capture_output=True, timeout=300)
    store.close()
    return out


@pytest.fixture(scope="module")
def client(sample_build_dir, sample_run):
    from starlette.testclient import TestClient

    from tavf_mapkit.view.server import create_app, load_view_data

    return TestClient(create_app(load_view_data(sample_build_dir, [sample_run])))


def _build_lanes(build: Path) -> int:
    summary = json.loads((build / "report" / "summary.json").read_text())
    return summary["stages"]["opendrive"]["lanes"]


def test_map_has_one_lane_feature_per_lane_of_the_build(client, sample_build_dir):
    data = client.get("/api/map").json()
    lanes = data["layers"]["lanes"]["features"]
    assert len(lanes) == data["lane_count"] == _build_lanes(sample_build_dir) > 0
    (south, west), (north, east) = data["bounds"]
    for feature in lanes:
        ring = np.array(feature["geometry"]["coordinates"][0])
        assert feature["geometry"]["type"] == "Polygon" and len(ring) >= 4
        assert np.all(ring[0] == ring[-1])
        # every vertex within the map's bounds (lon, lat order): the projection ran, and the right way round
        assert np.all((ring[:, 0] >= west - 1e-4) & (ring[:, 0] <= east + 1e-4))
        assert np.all((ring[:, 1] >= south - 1e-4) & (ring[:, 1] <= north + 1e-4))
        assert {"road", "lane", "type", "section_s0"} <= set(feature["properties"])
    assert {f["properties"]["type"] for f in lanes} >= {"driving"}


def test_findings_carry_rule_road_lane_s_as_validated(client, sample_build_dir):
    data = client.get("/api/map").json()
    validated = json.loads((sample_build_dir / "report" / "validate.json").read_text())["findings"]
    with_road = [f for f in validated if f["road"] is not None]
    features = data["layers"]["findings"]["features"]
    assert data["findings_total"] == len(validated)
    assert len(features) == len(with_road)
    for feature, finding in zip(features, with_road):
        properties = feature["properties"]
        assert {key: properties[key] for key in ("rule", "severity", "road", "lane", "s", "line", "message")} == \
            {key: finding[key] for key in ("rule", "severity", "road", "lane", "s", "line", "message")}


def test_a_finding_on_a_lane_stands_inside_that_lane(sample_build_dir):
    """place_on_road puts (road, lane, s) on the lane's centre: inside the lane's polygon of the lane layer."""
    from tavf_mapkit.opendrive import load_opendrive
    from tavf_mapkit.opendrive.layers import layer_features
    from tavf_mapkit.view.mapdata import place_on_road

    odr = load_opendrive(next(sample_build_dir.glob("*.xodr")))
    checked = 0
    for feature in layer_features(odr, "lane", 0.5):
        road = odr.road_by_id[feature.properties["road"]]
        section = int(road.section_index(feature.properties["section_s0"]))
        s0, s1 = feature.properties["section_s0"], road.section_end(section)
        if s1 - s0 < 2.0:
            continue
        s = s0 + 0.37 * (s1 - s0)
        point = shapely.Point(place_on_road(odr, road.id, feature.properties["lane"], s))
        lane = shapely.Polygon(feature.coordinates[:, :2])
        assert lane.buffer(1e-6).contains(point), (road.id, feature.properties["lane"], s)
        checked += 1
    assert checked > 20
    assert place_on_road(odr, "no such road", 1, 0.0) is None


def test_scene_lists_every_mesh_tile_and_collision_body(client, sample_build_dir):
    scene = client.get("/api/scene").json()
    mesh = json.loads((sample_build_dir / "mesh" / "mesh.json").read_text())
    world = json.loads((sample_build_dir / "collision" / "world.json").read_text())
    assert [t["url"] for t in scene["mesh"]["tiles"]] == [f"build/mesh/{t['file']}" for t in mesh["tiles"]]
    assert len(scene["collision"]["bodies"]) == len(world["bodies"]) > 0
    tile = client.get("/" + scene["mesh"]["tiles"][0]["url"])
    assert tile.status_code == 200 and tile.content[:4] == b"glTF"
    body = client.get("/" + scene["collision"]["bodies"][0]["url"])
    assert body.status_code == 200 and b"\nv " in body.content
    # only mesh/ and collision/ of the build are served, and nothing above them
    assert client.get("/build/mesh/../manifest.json").status_code == 404
    assert client.get("/build/manifest.json").status_code == 404


def test_run_replays_the_ego_as_recorded(client, sample_run):
    assert client.get("/api/runs").json() == [{"index": 0, "name": sample_run.name}]
    run = client.get("/api/runs/0").json()
    with (sample_run / "trajectory.csv").open(newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert len(run["ego"]["t"]) == len(rows)
    # trajectory.csv rounds: t to 1 ms, x and y to 0.1 mm, lat and lon to 1e-9 degrees
    for key, digits in (("t", 3), ("x", 4), ("y", 4), ("lat", 9), ("lon", 9)):
        np.testing.assert_allclose(run["ego"][key], [float(row[key]) for row in rows], rtol=0,
                                   atol=0.51 * 10.0 ** -digits, err_msg=key)
    frames = run["traffic"]["frames"]
    assert frames and any(frame["ids"] for frame in frames)
    for frame in frames:
        assert len(frame["ids"]) == len(frame["x"]) == len(frame["lat"]) == len(frame["lon"]) == len(frame["person"])
    assert run["lidar"] is None and any("lidar" in note for note in run["notes"])
    assert client.get("/api/runs/1").status_code == 404


def test_run_replays_the_udm_answers(client, sample_run, sample_build_dir):
    """Every UDM answer the drive recorded, at its simulated time, its objects in WGS84 and in the local frame."""
    from tavf_mapkit.opendrive import load_opendrive
    from twin.recording.reader import read_recording

    run = client.get("/api/runs/0").json()
    recorded = read_recording(sample_run / "session.mcap").udm_responses
    assert len(run["udm"]) == len(recorded) > 0
    georef = load_opendrive(next(sample_build_dir.glob("*.xodr"))).georeference
    duration = run["ego"]["t"][-1]
    for answer, record in zip(run["udm"], recorded):
        assert answer["step"] == record["step"] and 0 <= answer["t"] <= duration + 1.0
        assert [o["id"] for o in answer["objects"]] == [f["id"] for f in record["features"]]
        for obj in answer["objects"]:
            x, y = georef.wgs84_to_local(obj["lon"], obj["lat"])
            assert (obj["x"], obj["y"]) == pytest.approx((float(x), float(y)), abs=1e-3)
    assert any(answer["objects"] for answer in run["udm"] if answer["status"] == "ok")


def test_a_run_of_another_build_is_shown_with_a_note(sample_build_dir, sample_run, tmp_path):
    import shutil

    from tavf_mapkit.view.server import load_view_data

    other = tmp_path / "other"
    shutil.copytree(sample_build_dir, other)
    manifest = json.loads((other / "manifest.json").read_text())
    manifest["artifacts"]["xodr"]["sha256"] = "0" * 64  # another build of the map
    (other / "manifest.json").write_text(json.dumps(manifest))
    [run] = [json.loads(body) for body in load_view_data(other, [sample_run]).runs]
    assert run["notes"][0] == "driven on another build of the map (its OpenDRIVE sha256 differs)"
    [same] = [json.loads(body) for body in load_view_data(sample_build_dir, [sample_run]).runs]
    assert not any("another build" in note for note in same["notes"])


def test_page_and_vendored_scripts_are_served(client):
    page = client.get("/")
    assert page.status_code == 200 and "static/app.js" in page.text and '"basemap": false' in page.text
    for path in ("static/vendor/leaflet/leaflet.js", "static/vendor/three/build/three.module.min.js",
                 "static/vendor/three/examples/jsm/loaders/GLTFLoader.js", "static/map2d.js", "static/scene3d.js"):
        assert client.get("/" + path).status_code == 200, path


def test_not_a_build_is_one_line_exit_2(tmp_path):
    result = CliRunner().invoke(cli, ["view", str(tmp_path), "--no-browser"])
    assert result.exit_code == 2
    assert result.output.strip().splitlines() == [
        f"Error: {tmp_path}: not a build folder (no manifest.json; make one with `mapkit build`)"]


def test_not_a_run_is_one_line_exit_2(sample_build_dir, tmp_path):
    result = CliRunner().invoke(cli, ["view", str(sample_build_dir), str(tmp_path), "--no-browser"])
    assert result.exit_code == 2
    assert result.output.strip().splitlines() == [
        f"Error: {tmp_path}: not a run folder of `twin drive` (no session.mcap or trajectory.csv)"]


def test_a_taken_port_is_one_line_exit_2(sample_build_dir):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen(1)
        port = taken.getsockname()[1]
        result = CliRunner().invoke(cli, ["view", str(sample_build_dir), "--port", str(port), "--no-browser"])
    assert result.exit_code == 2
    [line] = result.output.strip().splitlines()
    assert line.startswith(f"Error: cannot listen on 127.0.0.1:{port}: ") and line.endswith(
        "(give another --port; 0 picks a free one)")


def test_output_writes_the_static_page(sample_build_dir, tmp_path):
    out = tmp_path / "page.html"
    result = CliRunner().invoke(cli, ["view", str(sample_build_dir), "-o", str(out), "--json"])
    assert result.exit_code == 0, result.output
    summary = json.loads(result.output)
    assert summary["lanes"] == _build_lanes(sample_build_dir)
    html = out.read_text()
    data = json.loads(html.split("window.MAPKIT_DATA = ", 1)[1].split(";\nwindow.mapkit", 1)[0])
    assert len(data["layers"]["lanes"]["features"]) == summary["lanes"]


def test_gnss_trace_and_matched_path(sample_build_dir, sample_run):
    """A noise-free GNSS trace of a drive: every fix on the page, matched, and on the matched path drawn."""
    from tavf_mapkit.opendrive import load_opendrive
    from tavf_mapkit.view.mapdata import map_data, match_gnss

    odr = load_opendrive(next(sample_build_dir.glob("*.xodr")))
    trace, result = match_gnss(odr, sample_run / "gnss.csv")
    layers = map_data(odr, name="sample", match=(trace, result))["layers"]
    fixes = layers["gnss"]["features"]
    assert len(fixes) == len(result) > 10
    assert all(f["properties"]["matched"] and f["properties"]["distance_m"] < 0.5 for f in fixes)
    assert len(layers["matched"]["features"]) == len(set(result.lane_route)) > 0
    # back in the local frame, every fix lies on the drawn path (within the drive's lateral error)
    lon_lat = np.array([f["geometry"]["coordinates"] for f in fixes])
    x, y = odr.georeference.wgs84_to_local(lon_lat[:, 0], lon_lat[:, 1])
    np.testing.assert_allclose(np.column_stack([x, y]), np.column_stack([result.x, result.y]), atol=0.02)
    path = shapely.MultiLineString([np.column_stack(odr.georeference.wgs84_to_local(*np.array(
        f["geometry"]["coordinates"]).T)) for f in layers["matched"]["features"]])
    assert max(path.distance(shapely.Point(p)) for p in zip(x, y)) < 0.5


@pytest.mark.parametrize("batch", [1, 7])
def test_map_json_in_batches_is_the_whole_maps_json(sample_build_dir, sample_run, batch):
    """The report's map text, made a few lanes at a time (map_json), is json.dumps of the whole map_data to the
    byte: findings, repairs, GNSS trace and matched path included; and so is the page made of its pieces."""
    from tavf_mapkit.opendrive import load_opendrive
    from tavf_mapkit.view.mapdata import map_data, map_json, match_gnss
    from tavf_mapkit.view.page import static_map, static_map_parts

    odr = load_opendrive(next(sample_build_dir.glob("*.xodr")))
    findings = json.loads((sample_build_dir / "report" / "validate.json").read_text())["findings"]
    manifest = json.loads((sample_build_dir / "manifest.json").read_text())
    repairs = next(stage["facts"].get("repairs") for stage in manifest["stages"] if stage["name"] == "opendrive")
    options = dict(name="sample", findings=findings, repairs=repairs, match=match_gnss(odr, sample_run / "gnss.csv"),
                   attribution="(c) OpenStreetMap contributors", step=2.5)
    extra = {"repair_counts": [{"repair": "x", "count": 1}], "findings_total": len(findings)}
    whole = map_data(odr, **options) | extra
    assert findings and whole["layers"]["gnss"]["features"] and whole["layers"]["marks"]["features"]
    assert whole["lane_count"] > 3 * batch  # several batches
    pieces = map_json(odr, **options, extra=extra, batch=batch)
    assert len(pieces) > 3 and "".join(pieces) == json.dumps(whole, separators=(",", ":"), allow_nan=False)
    # the page's body written from the pieces is the one made from the whole map (</ escaped the same)
    head, body = static_map_parts(pieces)
    assert (head, "".join(body)) == static_map(whole)


def test_view_without_a_display_serves_and_says_so(sample_build_dir):
    """Asked to open a browser where there is no display, mapkit view does not start one (a text browser would
    take the terminal, and the command would hang on it): it serves, says to open the address, and stops on
    SIGTERM."""
    import os
    import signal

    env = {key: value for key, value in os.environ.items() if key not in ("DISPLAY", "WAYLAND_DISPLAY")}
    mapkit = Path(sys.executable).parent / "mapkit"
    process = subprocess.Popen([str(mapkit), "view", str(sample_build_dir), "--port", "0"], env=env,
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        import queue
        import threading

        said: queue.Queue = queue.Queue()
        threading.Thread(target=lambda: [said.put(line.strip()) for line in process.stderr], daemon=True).start()
        lines = [said.get(timeout=60) for _ in range(2)]  # a line that never comes fails, never hangs
        assert lines[0].startswith("mapkit view: http://127.0.0.1:") and lines[0].endswith("(Ctrl-C to stop)")
        assert lines[1] == "mapkit view: no display to open a browser on; open the address above"
    finally:
        process.send_signal(signal.SIGTERM)
        assert process.wait(timeout=30) is not None
