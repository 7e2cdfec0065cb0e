"""Left-hand maps are built and driven on the left, right-hand maps on the right (the zoo's London, Singapore
and West Oakland extracts, built as a user would, with the side detected from where the map is).

netconvert writes every direction of a street as its own road with right lanes along s, on both sides of the
world (docs/driving-side.md), so the side is measured as a person on the street would see it: wherever the
twin's car (and each SUMO car) meets a lane of oncoming traffic beside it, that lane lies on its right in
left-hand traffic and on its left in right-hand traffic.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.spatial import cKDTree

from tests.conftest import shared_path

ONCOMING_RADIUS_M = 8.0  # a lane centre this close, heading the other way: the other half of the same street
ON_LANE_M = 1.5  # a pose this close to a lane centre of its own direction is driving on that lane
MAPS = [
    # zoo file, --bbox (London: the middle of the City, St Paul's to Bank, about 0.9 x 0.9 km, to keep CI short;
    # the whole extract reaches far west of the City), side, country
    ("GB_london_city_LHT.osm.pbf", "-0.1090,51.5120,-0.0960,51.5200", "left", "GB"),
    ("SG_bayfront_LHT.osm.pbf", None, "left", "SG"),
    ("US_west_oakland.osm.gz", None, "right", "US"),
]


class OncomingLanes:
    """Centre-line samples of the driving lanes outside junctions, with their direction of travel."""

    def __init__(self, xodr: Path):
        from tavf_mapkit.lanegraph import LaneGraph
        from tavf_mapkit.opendrive import load_opendrive

        odr = load_opendrive(xodr)
        graph = LaneGraph.from_opendrive(odr)
        points, directions = [], []
        for key in graph.keys:
            if odr.roads[key.road_index].in_junction:
                continue
            centre, _ = graph.centerline(key, 1.0)
            if len(centre) < 2:
                continue
            step = np.diff(centre[:, :2], axis=0)
            points.append(centre[:-1, :2])
            directions.append(step / np.maximum(np.linalg.norm(step, axis=1), 1e-9)[:, None])
        self.points, self.directions = np.vstack(points), np.vstack(directions)
        self.tree = cKDTree(self.points)

    def sides(self, x, y, yaw) -> tuple[int, int]:
        """(on the left, on the right): where the nearest oncoming lane lies, over poses on a lane outside
        junctions (on a lane centre, heading its way) that have one beside them; inside junctions and on
        turnarounds the other half of a curve can lie on either side."""
        left = right = 0
        for px, py, heading in zip(x, y, yaw):
            ahead = np.array([np.cos(heading), np.sin(heading)])
            near = np.array(self.tree.query_ball_point([px, py], ONCOMING_RADIUS_M), dtype=np.int64)
            if not len(near):
                continue
            along = self.directions[near] @ ahead
            on_lane = np.hypot(*(self.points[near[along > 0.9]] - (px, py)).T) < ON_LANE_M
            if not np.any(on_lane):
                continue
            oncoming = near[along < -0.9]
            if not len(oncoming):
                continue
            offset = self.points[oncoming] - (px, py)
            nearest = offset[np.argmin(np.hypot(offset[:, 0], offset[:, 1]))]
            if ahead[0] * nearest[1] - ahead[1] * nearest[0] > 0:
                left += 1
            else:
                right += 1
        return left, right


@pytest.mark.slow
@pytest.mark.parametrize("zoo_file, bbox, side, country", MAPS, ids=[m[0].split(".")[0] for m in MAPS])
def test_zoo_map_is_built_and_driven_on_its_side(zoo_file, bbox, side, country, tmp_path):
    from tavf_mapkit.cli.main import cli as mapkit_cli
    from twin.cli.main import cli as twin_cli
    from twin.recording.reader import read_recording

    source = shared_path("zoo", "osm", zoo_file)
    build = tmp_path / "build"
    arguments = ["build", str(source), "-o", str(build), "-q"] + (["--bbox", bbox] if bbox else [])
    result = CliRunner().invoke(mapkit_cli, arguments, catch_exceptions=False)
    assert result.exit_code == 0, result.output
    manifest = json.loads((build / "manifest.json").read_text())
    recorded = manifest["driving_side"]
    assert (recorded["side"], recorded["source"], recorded["country"]) == (side, "location", country)
    net = (build / "build.net.xml").read_text(encoding="utf-8")[:20000]
    assert ('lefthand="true"' in net) == (side == "left")

    run = tmp_path / "run"
    result = CliRunner().invoke(twin_cli, ["drive", "--map", str(build), "--random", "--duration", "150", "--seed",
                                           "0", "--traffic", "15", "-o", str(run), "--no-plot"],
                                catch_exceptions=False)
    assert result.exit_code == 0, result.output
    lanes = OncomingLanes(build / "build.xodr")

    rows = list(csv.DictReader((run / "trajectory.csv").open()))[::5]
    x, y, yaw = (np.array([float(row[key]) for row in rows]) for key in ("x", "y", "yaw"))
    left, right = lanes.sides(x, y, yaw)
    assert left + right >= 20, (left, right)  # the car met oncoming traffic lanes often enough to tell
    keeps_left = right / (left + right)
    assert keeps_left >= 0.95 if side == "left" else keeps_left <= 0.05, (left, right)

    tx, ty, tyaw = [], [], []
    for message in read_recording(run / "session.mcap", {"/traffic"}).messages("/traffic")[::10]:
        data = message.data
        moving = [i for i, (person, speed) in enumerate(zip(data["person"], data["speed"])) if not person and speed > 1]
        tx += [data["x"][i] for i in moving]
        ty += [data["y"][i] for i in moving]
        tyaw += [data["yaw"][i] for i in moving]
    left, right = lanes.sides(tx, ty, tyaw)
    assert left + right >= 50, (left, right)
    keeps_left = right / (left + right)
    assert keeps_left >= 0.95 if side == "left" else keeps_left <= 0.05, (left, right)
