"""The UDM in the loop of a real ``twin drive``: answers against a brute force, latencies, and faults."""

from __future__ import annotations

import asyncio
import csv
import json
import socket

import pytest
from click.testing import CliRunner
from starlette.applications import Starlette
from starlette.responses import JSONResponse, Response
from starlette.routing import Route

from twin.cli.main import cli
from twin.recording.reader import read_recording
from twin.udm.model import BBox, square_around
from twin.udm.seed import seed_from_build
from twin.udm.server import ServerThread, create_app
from twin.udm.store import SqliteRtreeStore

EVERY = 10
DURATION = "8"


def twin_drive(build, out, *extra: str) -> dict:
    result = CliRunner().invoke(cli, ["drive", "--map", str(build), "--random", "--duration", DURATION, "--seed",
                                      "4", "-o", str(out), "--no-plot", "--json", *extra],
                                catch_exceptions=False)
    assert result.exit_code == 0, result.output
    return json.loads(result.output[result.output.index("{"):])


@pytest.fixture(scope="module")
def seeded(sample_build_dir):
    store = SqliteRtreeStore()
    seed_from_build(store, sample_build_dir)
    with ServerThread(create_app(store, "token")) as server:
        yield server.url, store
    store.close()


@pytest.fixture(scope="module")
def baseline(sample_build_dir, tmp_path_factory):
    out = tmp_path_factory.mktemp("baseline") / "drive"
    twin_drive(sample_build_dir, out, "--no-record")
    return out


def latency_rows(out):
    with (out / "udm_latency.csv").open(newline="") as handle:
        return list(csv.DictReader(handle))


@pytest.mark.slow
def test_a_drive_asks_around_each_fix_and_gets_what_the_store_holds(sample_build_dir, seeded, tmp_path):
    url, store = seeded
    out = tmp_path / "drive"
    metrics = twin_drive(sample_build_dir, out, "--udm", url, "--udm-every", str(EVERY), "--udm-bbox", "300")
    udm = metrics["udm"]
    assert udm["error_count"] == 0 and udm["queries"] == int(float(DURATION) / 0.05) // EVERY + 1
    # every query is answered; the drive runs far faster than real time, so on a busy machine some answers
    # arrive only after the last step (late: logged, never seen by the simulation)
    assert udm["answers"] + udm["late_answers"] == udm["queries"] and udm["answers"] >= udm["queries"] // 2
    assert udm["latency_ms"]["request"]["n"] == udm["answers"]

    rows = [row for row in latency_rows(out) if row["step"]]
    assert len(rows) == udm["answers"]
    for row in rows:
        assert row["status"] == "ok" and int(row["frame"]) % EVERY == 0 and int(row["step"]) >= int(row["frame"])
        t_publish, t_sent, t_received, t_available = (float(row[k]) for k in ("t_publish", "t_sent", "t_received",
                                                                               "t_available"))
        assert t_publish <= t_sent <= t_received <= t_available

    recording = read_recording(out / "session.mcap")
    answers = recording.udm_responses
    assert [a["step"] for a in answers] == [int(row["step"]) for row in rows]
    everything = store.in_bbox(BBox(-180.0, -90.0, 180.0, 90.0))
    fixes = {state["step"]: state.get("gnss") for state in recording.ego_states}
    non_empty = 0
    for answer in answers:
        query = answer["query"]
        assert query["side_m"] == 300.0
        fix = fixes[answer["frame"]]  # the 10 Hz GNSS fires on every query step at dt 0.05
        assert (query["lat"], query["lon"]) == (fix["lat"], fix["lon"])
        box = square_around(query["lat"], query["lon"], 300.0)
        expected = {o.id for o in everything if box.contains(o.lat, o.lon)}  # brute force
        assert {feature["id"] for feature in answer["features"]} == expected
        non_empty += bool(expected)
    assert non_empty > 0  # the sample map's signals lie along the drive
    assert recording.messages("/udm/scene") and recording.messages("/udm/latency")


def closed_port_url() -> str:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return f"http://127.0.0.1:{sock.getsockname()[1]}"


async def slow(request):
    await asyncio.sleep(5.0)
    return JSONResponse({"type": "FeatureCollection", "features": []})


async def failing(request):
    return JSONResponse({"error": "internal_error"}, status_code=500)


async def garbage(request):
    return Response(b'{"type": "FeatureCollection", "features": [{"type": "Feat', media_type="application/json")


@pytest.mark.slow
@pytest.mark.parametrize(("handler", "status"), [(None, "unreachable"), (slow, "timeout"), (failing, "http_5xx"),
                                                 (garbage, "malformed")])
def test_a_broken_udm_is_counted_and_does_not_change_the_drive(sample_build_dir, baseline, tmp_path, handler,
                                                               status):
    out = tmp_path / "drive"
    if handler is None:
        metrics = twin_drive(sample_build_dir, out, "--udm", closed_port_url())
    else:
        with ServerThread(Starlette(routes=[Route("/{path:path}", handler)])) as server:
            metrics = twin_drive(sample_build_dir, out, "--udm", server.url)
    udm = metrics["udm"]
    assert metrics["hook_errors"] == 0
    assert set(udm["errors"]) == {status} and udm["error_count"] == udm["answers"] + udm["late_answers"] >= 1
    client = udm["client"]  # every query is accounted for: answered, pushed out of the queue, or left at the end
    assert client["submitted"] == udm["queries"] == (client["ok"] + sum(client["errors"].values())
                                                     + client["dropped"] + client["abandoned"])
    assert udm["latency_ms"] is None
    # Failed answers carry no objects, so the drive is the one without a UDM, byte for byte.
    assert (out / "trajectory.csv").read_bytes() == (baseline / "trajectory.csv").read_bytes()
    logged = {row["status"] for row in latency_rows(out)}
    assert logged == {status}
    answers = read_recording(out / "session.mcap").udm_responses
    assert len(answers) == udm["answers"]
    assert all(answer["status"] == status and answer["features"] == [] for answer in answers)
