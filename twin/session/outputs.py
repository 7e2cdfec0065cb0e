"""Session outputs: a staging folder put in place at the end (``fileutil.StagedFolder``), and the CSV/JSON
writers.

Numbers are written with fixed formats (not repr), so two runs with the same seed and inputs produce
byte-identical files.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from tavf_mapkit.fileutil import StagedFolder

TRAJECTORY_HEADER = "t,x,y,z,yaw,speed,lat,lon,road,lane"
GNSS_HEADER = "t,lat,lon,alt,x,y,z"
MARKER = "metrics.json"  # a folder holding this was written by twin drive and may be replaced


def output_folder(path: str | Path) -> StagedFolder:
    """``--out``, written in a staging folder beside it (``.staging``) until ``commit()`` puts it in place whole;
    an existing folder is replaced only if twin drive wrote it."""
    return StagedFolder(path, marker=MARKER, what="the output folder",
                        refusal="output exists and is not a twin drive output folder; choose another --out").open()


def _column(values: np.ndarray, digits: int) -> list[str]:
    return [f"{v:.{digits}f}" for v in np.asarray(values, dtype=float).tolist()]


def write_trajectory(path: Path, t, x, y, z, yaw, speed, lat, lon, road: list[str], lane) -> None:
    columns = [_column(t, 3), _column(x, 4), _column(y, 4), _column(z, 4), _column(yaw, 6), _column(speed, 4),
               _column(lat, 9), _column(lon, 9), [_csv_text(r) for r in road], [str(int(v)) for v in lane]]
    lines = [TRAJECTORY_HEADER] + [",".join(row) for row in zip(*columns)]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def write_gnss(path: Path, fixes) -> None:
    lines = [GNSS_HEADER]
    for f in fixes:
        lines.append(f"{f.t:.3f},{f.lat:.9f},{f.lon:.9f},{f.alt:.4f},{f.x:.4f},{f.y:.4f},{f.z:.4f}")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def write_imu(path: Path, samples) -> None:
    lines = ["t,speed,yaw_rate,accel_x,accel_y"]
    for s in samples:
        lines.append(f"{s.t:.3f},{s.speed:.4f},{s.yaw_rate:.6f},{s.accel_x:.4f},{s.accel_y:.4f}")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def write_collisions(path: Path, collisions) -> None:
    lines = ["t,vehicle,kind,other,x,y,detail"]
    for c in collisions:
        lines.append(f"{c.t:.3f},{c.vehicle},{_csv_text(c.kind)},{_csv_text(c.other)},{c.x:.3f},{c.y:.3f},"
                     f"{_csv_text(c.detail)}")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def write_metrics(path: Path, metrics: dict) -> None:
    path.write_text(json.dumps(_finite(metrics), indent=2) + "\n", encoding="utf-8")


def _finite(value):
    """JSON has no NaN/inf: they become null."""
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    return value


def _csv_text(text: str) -> str:
    text = str(text)
    if any(c in text for c in ',"\n'):
        return '"' + text.replace('"', '""') + '"'
    return text
