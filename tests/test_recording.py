"""Session recordings: exact round trips, Foxglove's schema contracts, and what a killed writer leaves."""

from __future__ import annotations

import json
import math
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader

from tavf_mapkit.errors import InputError
from twin.recording.hook import SessionRecording, json_safe
from twin.recording.messages import ego_pose, location_fix, quaternion, udm_scene
from twin.recording.reader import read_recording
from twin.recording.schemas import (
    CHANNELS,
    EGO_STATE_CHANNEL,
    GNSS_CHANNEL,
    UDM_RESPONSE_CHANNEL,
    UDM_SCENE_CHANNEL,
)
from twin.recording.writer import Recorder, encode
from twin.sensors.fix import GnssFix
from twin.session.hooks import Frame
from twin.udm.model import Extent, UdmObject

# Required fields of Foxglove's published schemas (docs.foxglove.dev, foxglove-sdk schemas/jsonschema).
FOXGLOVE_REQUIRED = {
    "foxglove.LocationFix": {"timestamp", "frame_id", "latitude", "longitude", "altitude", "position_covariance",
                             "position_covariance_type"},
    "foxglove.PoseInFrame": {"timestamp", "frame_id", "pose"},
    "foxglove.FrameTransform": {"timestamp", "parent_frame_id", "child_frame_id", "translation", "rotation"},
    "foxglove.SceneUpdate": {"deletions", "entities"},
    "foxglove.GeoJSON": {"geojson"},
}


def frame(step: int, gnss: bool = False) -> Frame:
    t = step * 0.05
    fix = GnssFix(t, 53.55 + step * 1e-7, 9.99 + step * 1e-7, 12.5, 1.0 / 3.0, 2.0 / 7.0, 0.1, 0.5) if gnss else None
    return Frame(t=t, step=step, x=100.0 + step / 3.0, y=-50.0 + math.pi * step, z=0.123456789, yaw=0.1 * step,
                 speed=8.333333333333334, lat=53.55 + step * 1e-7, lon=9.99 + 3e-7 * step, road_id="r1",
                 lane_id=-1, gnss=fix, pitch=1e-17, roll=-2.5e-300)


def test_ego_states_and_udm_answers_round_trip_exactly(tmp_path):
    path = tmp_path / "session.mcap"
    recording = SessionRecording(path)
    recording.config({"seed": 7, "map": tmp_path, "options": (1, 2)}, dt=0.05)
    frames = [frame(step, gnss=step % 2 == 0) for step in range(40)]
    for item in frames:
        recording.frame(item)
    obj = UdmObject(id="rw-1", layer=3, type="roadworks", lat=53.5501234567891, lon=9.990000000000001,
                    heading=12.5, extent=Extent(10.0, 3.5), valid_until=1.7e9 + 1 / 3, source="feed",
                    created_at=1.6e9 + 0.1)
    recording.udm_response(1.0, 20, {"frame": 10, "status": "ok", "loop_latency_s": 0.0042}, [obj])
    recording.metrics(2.0, {"sim_seconds": 2.0})
    recording.close()

    read = read_recording(path)
    assert read.complete
    assert read.config == {"config": {"seed": 7, "map": str(tmp_path), "options": [1, 2]}, "dt": 0.05}
    states = read.ego_states
    assert len(states) == 40
    for item, state in zip(frames, states, strict=True):
        for name in ("t", "step", "x", "y", "z", "yaw", "speed", "lat", "lon", "pitch", "roll"):
            assert state[name] == getattr(item, name)  # bit for bit
    assert states[2]["gnss"]["x"] == 1.0 / 3.0 and "gnss" not in states[1]
    (answer,) = read.udm_responses
    assert answer["step"] == 20 and UdmObject.from_record(answer["features"][0]) == obj
    assert UdmObject.from_record(answer["features"][0]).created_at == obj.created_at
    assert read.metrics == {"sim_seconds": 2.0}
    assert len(read.messages(GNSS_CHANNEL.topic)) == 20


def test_channels_carry_foxglove_schemas_as_jsonschema_and_json_messages(tmp_path):
    path = tmp_path / "session.mcap"
    recording = SessionRecording(path)
    for step in range(3):
        recording.frame(frame(step, gnss=True))
    recording.udm_response(0.1, 2, {"frame": 0, "status": "ok"},
                           [UdmObject(id="s", layer=2, type="traffic_signals", lat=53.55, lon=9.99)])
    recording.close()
    with path.open("rb") as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()  # a finished recording has the index Foxglove uses to seek
        schemas = {schema.id: schema for schema in summary.schemas.values()}
        channels = {channel.topic: channel for channel in summary.channels.values()}
        for topic, channel in channels.items():
            schema = schemas[channel.schema_id]
            assert channel.message_encoding == "json" and schema.encoding == "jsonschema", topic
            assert json.loads(schema.data)["title"] == schema.name
        seen = set()
        for schema, channel, message in reader.iter_messages():
            data = json.loads(message.data)
            if schema.name in FOXGLOVE_REQUIRED:
                assert FOXGLOVE_REQUIRED[schema.name] <= set(data), schema.name
                seen.add(schema.name)
            declared = json.loads(schema.data)
            assert set(declared.get("required", ())) <= set(data), channel.topic
    assert seen == set(FOXGLOVE_REQUIRED)
    assert {channel.topic for channel in CHANNELS} >= set(channels)


def test_message_builders_follow_foxglove_conventions():
    q = quaternion(math.pi / 2)
    assert math.isclose(q["z"], math.sqrt(0.5)) and math.isclose(q["w"], math.sqrt(0.5))
    assert math.isclose(sum(v * v for v in quaternion(0.3, 0.2, -0.1).values()), 1.0)
    pose = ego_pose(frame(3), 1_500_000_000_250_000_000)
    assert pose["timestamp"] == {"sec": 1_500_000_000, "nsec": 250_000_000} and pose["frame_id"] == "map"
    fix = location_fix(GnssFix(0.0, 53.5, 9.9, 10.0, 0, 0, 0, sigma_m=0.5), 0)
    assert fix["position_covariance"][0] == fix["position_covariance"][4] == fix["position_covariance"][8] == 0.25
    assert fix["position_covariance_type"] == 2  # DIAGONAL_KNOWN
    scene = udm_scene([], None, 0.0, 0)
    assert scene["deletions"][0]["type"] == 1 and scene["entities"] == []  # ALL: the scene is replaced
    assert json.loads(encode({"a": float("nan"), "b": [float("inf")]})) == {"a": None, "b": [None]}
    assert json_safe({"p": Path("/x"), 1: (2, 3)}) == {"p": "/x", "1": [2, 3]}


WRITER_SCRIPT = textwrap.dedent("""
    import sys, time
    from twin.recording.writer import Recorder
    from twin.recording.schemas import EGO_STATE_CHANNEL
    recorder = Recorder(sys.argv[1], flush_interval_s=0.5)
    step = 0
    while True:
        recorder.write(EGO_STATE_CHANNEL, step * 0.05, {"t": step * 0.05, "step": step, "x": 0.0, "y": 0.0,
                                                         "z": 0.0, "yaw": 0.0, "speed": 0.0, "wall": time.time()})
        step += 1
        if step == 1:
            print("started", flush=True)
        time.sleep(0.001)
""")


def test_a_killed_writer_loses_at_most_about_a_second(tmp_path):
    path = tmp_path / "killed.mcap"
    process = subprocess.Popen([sys.executable, "-c", WRITER_SCRIPT, str(path)], stdout=subprocess.PIPE, text=True)
    try:
        assert process.stdout.readline().strip() == "started"
        time.sleep(2.5)
        killed_at = time.time()
        process.send_signal(signal.SIGKILL)
    finally:
        process.wait(10)
    recording = read_recording(path)
    assert not recording.complete
    states = recording.ego_states
    assert len(states) > 100
    assert [state["step"] for state in states] == list(range(len(states)))  # nothing garbled, no gaps
    lost_s = killed_at - states[-1]["wall"]
    assert 0.0 <= lost_s <= 1.0, lost_s


def test_unreadable_recordings_give_one_line_input_errors(tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        read_recording(tmp_path / "missing.mcap")
    text = tmp_path / "notes.mcap"
    text.write_text("hello, this is not MCAP")
    with pytest.raises(InputError, match="not an MCAP file") as error:
        read_recording(text)
    assert "notes.mcap" in str(error.value) and "\n" not in str(error.value)
    truncated = tmp_path / "short.mcap"
    truncated.write_bytes(b"\x89MCAP0\r\n\x01")
    with pytest.raises(InputError, match="not a readable MCAP recording"):
        read_recording(truncated)


def test_recorder_flushes_on_its_interval_without_closing(tmp_path):
    path = tmp_path / "open.mcap"
    recorder = Recorder(path, flush_interval_s=0.0)  # every write completes a chunk
    for step in range(5):
        recorder.write(EGO_STATE_CHANNEL, step, {"t": step, "step": step})
    recorder.write(UDM_RESPONSE_CHANNEL, 5, {"step": 5, "frame": 0, "status": "ok", "features": []})
    recorder.write(UDM_SCENE_CHANNEL, 5, {"deletions": [], "entities": []})
    partial = read_recording(path)  # still open: no footer yet, everything written is readable
    assert not partial.complete and len(partial.ego_states) == 5 and len(partial.udm_responses) == 1
    recorder.close()
    recorder.close()
    assert read_recording(path).complete
