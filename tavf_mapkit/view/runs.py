"""A ``twin drive`` output folder as replay data for both views: per time step the ego (local x, y, z, yaw and
WGS84), the SUMO vehicles and pedestrians of the ``/traffic`` channel, and the UDM objects of each answer.

Read from the folder's ``session.mcap`` (docs/recording.md); a drive recorded with ``--no-record`` still
replays its ego from ``trajectory.csv``. Lidar points are not in the recording (the twin records no point
clouds), so the replay has none; the page says so.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

from tavf_mapkit.errors import InputError

MAX_EGO_SAMPLES = 20_000     # a longer drive is thinned evenly (the slider cannot show more anyway)
MAX_TRAFFIC_FRAMES = 6_000


def load_run(folder: str | Path, georef) -> dict:
    """The replay of one run folder, JSON-ready. ``georef``: the build's display georeference (the traffic
    channel holds local x, y only)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError("not a run folder (no such directory)", file=str(folder))
    mcap = folder / "session.mcap"
    trajectory = folder / "trajectory.csv"
    if mcap.is_file():
        run = _from_recording(mcap, georef)
    elif trajectory.is_file():
        run = {"ego": _ego_from_csv(trajectory), "traffic": None, "udm": [], "config": None}
    else:
        raise InputError("not a run folder of `twin drive` (no session.mcap or trajectory.csv)", file=str(folder))
    metrics = folder / "metrics.json"
    try:
        run["metrics"] = json.loads(metrics.read_text(encoding="utf-8")) if metrics.is_file() else None
    except ValueError:
        run["metrics"] = None
    run["name"] = folder.name
    run["lidar"] = None
    run["notes"] = ["lidar points: not recorded (the twin's recording holds no point clouds)"]
    if not len(run["ego"]["t"]):
        raise InputError("the run holds no ego states", file=str(folder))
    return run


def _from_recording(path: Path, georef) -> dict:
    from twin.recording.reader import read_recording

    recording = read_recording(path)
    states = recording.ego_states
    fields = ("t", "x", "y", "z", "yaw", "speed", "lat", "lon")
    keep = _thin(len(states), MAX_EGO_SAMPLES)
    ego = {key: [_finite(states[i].get(key)) for i in keep] for key in fields}
    ego["road"] = [states[i].get("road_id") for i in keep]
    ego["lane"] = [states[i].get("lane_id") for i in keep]
    traffic = [message.data for message in recording.messages("/traffic")]
    # log times are the wall clock at the start plus simulated time (docs/recording.md): relative to the first
    # ego state they are simulated seconds
    ego_messages = recording.messages("/ego/state")
    start = ego_messages[0].log_time if ego_messages else 0
    udm = [{"t": (message.log_time - start) / 1e9, **_udm_answer(message.data)}
           for message in recording.messages("/udm/response")]
    config = recording.config or {}
    return {"ego": ego, "traffic": _traffic(traffic, georef) if traffic else None, "udm": udm,
            "config": {key: (config.get("config") or {}).get(key)
                       for key in ("seed", "duration", "traffic", "pedestrians", "lidar", "udm", "map_name",
                                   "map_sha256")}}


def _udm_answer(data: dict) -> dict:
    objects = [{"id": f.get("id"), "layer": f.get("layer"), "type": f.get("type"), "lat": f.get("lat"),
                "lon": f.get("lon"), "heading": f.get("heading"), "extent": f.get("extent")}
               for f in data.get("features") or ()]
    return {"step": data.get("step"), "status": data.get("status"), "objects": objects}


def _traffic(frames: list[dict], georef) -> dict:
    """Frames {t, ids, person, x, y, z, yaw, length, width, lat, lon} (one list per frame, thinned evenly)."""
    frames = [frames[i] for i in _thin(len(frames), MAX_TRAFFIC_FRAMES)]
    counts = np.array([len(frame.get("ids") or ()) for frame in frames], dtype=np.int64)
    x = np.concatenate([np.asarray(frame.get("x") or (), dtype=float) for frame in frames]) if len(frames) else []
    y = np.concatenate([np.asarray(frame.get("y") or (), dtype=float) for frame in frames]) if len(frames) else []
    lon, lat = georef.local_to_wgs84(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
    cuts = np.cumsum(counts)[:-1]
    lon_parts = np.split(np.round(np.atleast_1d(lon), 7), cuts)
    lat_parts = np.split(np.round(np.atleast_1d(lat), 7), cuts)
    out = []
    for frame, frame_lon, frame_lat in zip(frames, lon_parts, lat_parts):
        out.append({key: frame.get(key) for key in ("t", "ids", "person", "x", "y", "z", "yaw", "length", "width")}
                   | {"lon": frame_lon.tolist(), "lat": frame_lat.tolist()})
    return {"frames": out}


def _ego_from_csv(path: Path) -> dict:
    with path.open(newline="", encoding="utf-8") as handle:
        rows = list(csv.DictReader(handle))
    keep = _thin(len(rows), MAX_EGO_SAMPLES)
    ego = {key: [_finite(_number(rows[i].get(key))) for i in keep]
           for key in ("t", "x", "y", "z", "yaw", "speed", "lat", "lon")}
    ego["road"] = [rows[i].get("road") for i in keep]
    ego["lane"] = [rows[i].get("lane") for i in keep]
    return ego


def _thin(n: int, most: int) -> list[int]:
    if n <= most:
        return list(range(n))
    return sorted(set(np.linspace(0, n - 1, most).round().astype(int).tolist()))


def _number(text):
    try:
        return float(text)
    except (TypeError, ValueError):
        return None


def _finite(value):
    return value if isinstance(value, (int, float)) and np.isfinite(value) else None
