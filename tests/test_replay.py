"""``twin replay``: kinematic replay and re-simulation of a recorded drive with UDM answers that matter."""

from __future__ import annotations

import csv
import json
import shutil

import numpy as np
import pytest
from click.testing import CliRunner
from mcap.reader import make_reader
from mcap.writer import Writer

from twin.cli.main import cli
from twin.recording.reader import read_recording
from twin.udm.loop import CAUTION_SPEED_MS
from twin.udm.model import UdmObject
from twin.udm.server import ServerThread, create_app
from twin.udm.store import SqliteRtreeStore

DRIVE = ["--random", "--duration", "14", "--seed", "2", "--no-plot", "--json"]


def twin(*args: str):
    return CliRunner().invoke(cli, list(args), catch_exceptions=False)


def trajectory(out):
    with (out / "trajectory.csv").open(newline="") as handle:
        rows = list(csv.DictReader(handle))
    return {key: np.array([float(row[key]) for row in rows]) for key in ("t", "x", "y", "speed", "lat", "lon")}


@pytest.fixture(scope="module")
def hazard_drive(sample_build_dir, tmp_path_factory):
    """A drive without UDM, then the same drive with roadworks reported on its path from the UDM."""
    root = tmp_path_factory.mktemp("replay")
    result = twin("drive", "--map", str(sample_build_dir), "-o", str(root / "plain"), "--no-record", *DRIVE)
    assert result.exit_code == 0, result.output
    plain = trajectory(root / "plain")
    index = int(np.argmin(np.abs(plain["t"] - 9.0)))
    assert plain["speed"][index] > CAUTION_SPEED_MS + 1.0  # the hazard must be somewhere the car is fast
    store = SqliteRtreeStore()
    store.upsert([UdmObject(id="roadworks-1", layer=3, type="roadworks", lat=float(plain["lat"][index]),
                            lon=float(plain["lon"][index]), source="test")])
    with ServerThread(create_app(store, "token")) as server:
        result = twin("drive", "--map", str(sample_build_dir), "-o", str(root / "udm"), "--udm", server.url,
                      *DRIVE)
    assert result.exit_code == 0, result.output
    return root, plain, (plain["x"][index], plain["y"][index])


@pytest.mark.slow
def test_udm_roadworks_slow_the_car_down(hazard_drive):
    root, plain, (hx, hy) = hazard_drive
    cautious = trajectory(root / "udm")
    metrics = json.loads((root / "udm" / "metrics.json").read_text())
    assert metrics["udm"]["error_count"] == 0 and metrics["udm"]["answers"] > 0
    near = np.hypot(cautious["x"] - hx, cautious["y"] - hy) < 5.0
    assert near.any()
    assert cautious["speed"][near].max() <= CAUTION_SPEED_MS + 0.05
    assert not np.array_equal(cautious["x"], plain["x"][: len(cautious["x"])])


@pytest.mark.slow
def test_resimulation_reproduces_the_drive_exactly(hazard_drive):
    root, _, _ = hazard_drive
    result = twin("replay", "--resimulate", str(root / "udm" / "session.mcap"), "--json")
    assert result.exit_code == 0, result.output
    report = json.loads(result.output)
    assert report["identical"] and report["max_difference_overall"] == 0.0
    assert report["steps_compared"] == report["steps_recorded"] == 281


def copy_recording(source, target, *, empty_answers=False, chunk_size=1024 * 1024, nudge_traffic_at=None):
    """A copy of a recording, re-chunked; with ``empty_answers`` the UDM answers lose their objects, with
    ``nudge_traffic_at`` the first SUMO vehicle of that /traffic step moves 1 cm."""
    with source.open("rb") as reading, target.open("wb") as writing:
        reader = make_reader(reading)
        writer = Writer(writing, chunk_size=chunk_size)
        writer.start()
        schema_ids, channel_ids = {}, {}
        for schema, channel, message in reader.iter_messages():
            if schema.id not in schema_ids:
                schema_ids[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channel_ids:
                channel_ids[channel.id] = writer.register_channel(channel.topic, channel.message_encoding,
                                                                  schema_ids[schema.id])
            data = message.data
            if empty_answers and channel.topic == "/udm/response":
                answer = json.loads(data)
                answer["features"] = []
                data = json.dumps(answer).encode()
            if channel.topic == "/traffic" and json.loads(data)["step"] == nudge_traffic_at:
                tick = json.loads(data)
                tick["x"][0] += 0.01
                data = json.dumps(tick).encode()
            writer.add_message(channel_ids[channel.id], message.log_time, data, message.publish_time)
        writer.finish()


@pytest.mark.slow
def test_resimulation_uses_the_recorded_answers_and_reports_where_drives_part(hazard_drive, tmp_path):
    root, _, _ = hazard_drive
    tampered = tmp_path / "tampered.mcap"
    copy_recording(root / "udm" / "session.mcap", tampered, empty_answers=True)
    result = twin("replay", "--resimulate", str(tampered))
    assert result.exit_code == 1
    assert result.output.startswith("DIFFERENT") and "first difference at step" in result.output


@pytest.mark.slow
def test_a_recording_cut_short_is_resimulated_as_far_as_it_goes(hazard_drive, tmp_path):
    root, _, _ = hazard_drive
    small_chunks = tmp_path / "chunked.mcap"  # as a long drive flushed every half second would be
    copy_recording(root / "udm" / "session.mcap", small_chunks, chunk_size=8 * 1024)
    data = small_chunks.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    recording = read_recording(cut)
    assert not recording.complete and 0 < len(recording.ego_states) < 281
    result = twin("replay", "--resimulate", str(cut), "--json")
    assert result.exit_code == 0, result.output
    report = json.loads(result.output)
    assert report["identical"] and report["steps_compared"] == len(recording.ego_states)
    assert not report["recording_complete"]


@pytest.mark.slow
def test_kinematic_replay_prints_the_recorded_trajectory(hazard_drive, tmp_path):
    root, _, _ = hazard_drive
    out = tmp_path / "replayed.csv"
    result = twin("replay", str(root / "udm" / "session.mcap"), "-o", str(out))
    assert result.exit_code == 0, result.output
    with out.open(newline="") as handle:
        replayed = list(csv.DictReader(handle))
    driven = trajectory(root / "udm")
    assert len(replayed) == len(driven["t"])
    for key in ("x", "y", "speed"):  # trajectory.csv rounds to 4 decimals; the recording is exact
        np.testing.assert_allclose([float(row[key]) for row in replayed], driven[key], atol=5.1e-5)
    printed = twin("replay", str(root / "udm" / "session.mcap"), "--speed", "1000")
    assert printed.exit_code == 0 and printed.output.splitlines()[1:] == out.read_text().splitlines()[1:]


def test_replay_refuses_what_is_not_a_recording(tmp_path):
    bogus = tmp_path / "bogus.mcap"
    bogus.write_text("not an mcap")
    result = CliRunner().invoke(cli, ["replay", str(bogus)])
    assert result.exit_code == 2 and "not an MCAP file" in result.output
    assert result.output.strip().count("\n") == 0
    missing = CliRunner().invoke(cli, ["replay", "--resimulate", str(tmp_path / "none.mcap")])
    assert missing.exit_code == 2 and "does not exist" in missing.output


@pytest.mark.slow
def test_resimulation_refuses_a_different_map(hazard_drive, sample_build_dir, tmp_path):
    root, _, _ = hazard_drive
    other = tmp_path / "other"
    shutil.copytree(sample_build_dir, other)
    manifest = json.loads((other / "manifest.json").read_text())
    manifest["artifacts"]["xodr"]["sha256"] = "0" * 64  # as if the map had been rebuilt differently
    (other / "manifest.json").write_text(json.dumps(manifest))
    result = CliRunner().invoke(cli, ["replay", "--resimulate", str(root / "udm" / "session.mcap"), "--map",
                                      str(other)])
    assert result.exit_code == 2 and "map differs from the recorded one" in result.output


@pytest.mark.slow
def test_resimulation_compares_the_sumo_traffic_too(sample_build_dir, tmp_path):
    out = tmp_path / "traffic"
    result = twin("drive", "--map", str(sample_build_dir), "-o", str(out), "--random", "--duration", "12",
                  "--seed", "3", "--traffic", "8", "--no-plot", "--json")
    assert result.exit_code == 0, result.output
    ticks = read_recording(out / "session.mcap").messages("/traffic")
    assert len(ticks) >= 100 and any(tick.data["ids"] for tick in ticks)
    result = twin("replay", "--resimulate", str(out / "session.mcap"), "--json")
    assert result.exit_code == 0, result.output
    report = json.loads(result.output)
    assert report["identical"] and report["traffic_recorded"] == report["traffic_resimulated"] == len(ticks)
    assert report["traffic_mismatched"] == 0
    # one vehicle 1 cm off in one recorded tick: the ego is the same, the traffic is not
    step = next(tick.data["step"] for tick in ticks[len(ticks) // 2:] if tick.data["ids"])
    nudged = tmp_path / "nudged.mcap"
    copy_recording(out / "session.mcap", nudged, nudge_traffic_at=step)
    result = twin("replay", "--resimulate", str(nudged))
    assert result.exit_code == 1
    assert result.output.startswith("DIFFERENT") and "max difference 0" in result.output.splitlines()[0]
    assert f"first traffic difference at step {step}" in result.output
