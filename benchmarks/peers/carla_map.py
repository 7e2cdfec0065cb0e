"""CARLA 0.9.16's client-side map (PyPI ``carla``, its own venv; no simulator server needed).

    >>> points = waypoints("map.xodr", 2.0)            # structured: road, section, lane, s, x, y, z
    >>> agreement = centre_agreement(load_opendrive("map.xodr"), points)     # centres.py

``carla.Map(name, xodr_text).generate_waypoints(distance)`` puts waypoints on the centre line of every driving
lane. CARLA mirrors y (its frame is left-handed); it is mirrored back here. Its locations are single-precision
floats (about 0.1 mm steps a kilometre from the origin), and it evaluates a paramPoly3 as a polyline, so lanes
far from a short tight curve can be centimetres off even in a consistent file: report it, do not chase it.
"""

from __future__ import annotations

import io
import subprocess
from pathlib import Path

from .cache import peer_venv

REQUIREMENT = "carla==0.9.16"
WAYPOINT_FIELDS = [("road", "i8"), ("section", "i4"), ("lane", "i4"), ("s", "f8"), ("x", "f8"), ("y", "f8"),
                   ("z", "f8")]

_DUMP = r"""
import sys
import carla
with open(sys.argv[1], encoding="utf-8") as stream:
    text = stream.read()
out = sys.stdout
out.write("road,section,lane,s,x,y,z\n")
for w in carla.Map("peer", text).generate_waypoints(float(sys.argv[2])):
    p = w.transform.location
    out.write(f"{w.road_id},{w.section_id},{w.lane_id},{w.s!r},{p.x!r},{-p.y!r},{p.z!r}\n")
"""


def python(install: bool = False) -> Path:
    """The Python of the peer's venv (benchmarks/.peers/carla)."""
    return peer_venv("carla", REQUIREMENT, "bin/python", install)


def waypoints(xodr: Path | str, distance: float = 2.0, interpreter: Path | None = None):
    """CARLA's waypoints every ``distance`` metres on each driving lane, in the file's (right-handed) frame:
    a structured array of WAYPOINT_FIELDS."""
    import numpy as np  # here, not at the top: install.py, which installs the peer, needs no numpy

    done = subprocess.run(
        [str(interpreter or python()), "-c", _DUMP, str(xodr), repr(float(distance))],
        capture_output=True,
        text=True,
        timeout=900,
        check=False,
    )
    if done.returncode != 0:
        raise RuntimeError(
            f"carla.Map failed on {xodr} (exit {done.returncode}): "
            f"{(done.stderr.strip().splitlines() or ['no output'])[-1][:300]}"
        )
    return np.loadtxt(io.StringIO(done.stdout), delimiter=",", skiprows=1, dtype=WAYPOINT_FIELDS, ndmin=1)
