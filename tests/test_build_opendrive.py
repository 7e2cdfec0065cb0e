"""``mapkit build FILE.xodr``: the stages after netconvert on the user's own OpenDRIVE, and a drive through it.

The map is esmini's route-strategy test network (19 roads, 4 junctions, every road ``rule="LHT"``, no
geoReference): a left-hand OpenDRIVE file that has what an OSM build never has.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from tavf_mapkit.cli.main import cli as mapkit_cli

XODR = ("zoo", "xodr", "esmini_route_strategy_test_road_LHT.xodr")


def _mapkit(*args: str):
    return CliRunner().invoke(mapkit_cli, list(args), catch_exceptions=False)


@pytest.fixture(scope="module")
def lht_build(tmp_path_factory) -> tuple[Path, Path]:
    from tests.conftest import shared_path

    source = shared_path(*XODR)
    out = tmp_path_factory.mktemp("xodr-build") / "esmini"
    result = _mapkit("build", str(source), "-o", str(out))
    assert result.exit_code == 0, result.output
    return source, out


def test_opendrive_input_skips_extract_and_netconvert(lht_build):
    source, out = lht_build
    manifest = json.loads((out / "manifest.json").read_text())
    status = {record["name"]: (record["status"], record.get("note")) for record in manifest["stages"]}
    assert status["extract"] == ("skipped", "not for OpenDRIVE input")
    assert status["netconvert"] == ("skipped", "not for OpenDRIVE input")
    assert all(status[name][0] == "ran" for name in ("opendrive", "mesh", "collision", "check", "report"))
    assert manifest["input"]["kind"] == "opendrive"
    # the build's map is the user's file byte for byte; there is no SUMO network
    assert (out / "esmini.xodr").read_bytes() == source.read_bytes()
    assert manifest["artifacts"]["xodr"]["path"] == "esmini.xodr"
    assert "net" not in manifest["artifacts"] and not list(out.glob("*.net.xml"))
    assert (out / "collision" / "world.json").is_file()
    side = manifest["driving_side"]
    assert (side["side"], side["source"]) == ("left", "opendrive")
    assert side["reason"] == 'left-hand traffic: 19 of 19 roads have rule="LHT"'
    assert manifest["georeference"] is None


def test_rebuild_reuses_every_stage(lht_build):
    source, out = lht_build
    result = _mapkit("build", str(source), "-o", str(out), "--json")
    assert result.exit_code == 0, result.output
    stages = {stage["name"]: stage["status"] for stage in json.loads(result.stdout)["stages"]}
    assert stages == {"extract": "skipped", "netconvert": "skipped", "opendrive": "unchanged",
                      "mesh": "unchanged", "collision": "unchanged", "check": "unchanged", "report": "unchanged"}


def test_driving_side_override_rewrites_the_build_copy_only(lht_build, tmp_path):
    from tavf_mapkit.opendrive import load_opendrive

    source, _ = lht_build
    before = source.read_bytes()
    out = tmp_path / "rht"
    result = _mapkit("build", str(source), "-o", str(out), "--driving-side", "right")
    assert result.exit_code == 0, result.output
    assert source.read_bytes() == before
    odr = load_opendrive(out / "rht.xodr")
    assert len(odr.roads) == 19 and {road.rule for road in odr.roads} == {"RHT"}
    side = json.loads((out / "manifest.json").read_text())["driving_side"]
    assert (side["side"], side["source"]) == ("right", "option")


def test_drive_keeps_left_of_the_reference_line(lht_build, tmp_path):
    """The car drives on the side rule="LHT" says: left of its road's reference line in its direction of travel
    (positive lanes along s, negative against it), measured from the pose, not from the lane ids."""
    from tavf_mapkit.opendrive import load_opendrive
    from tavf_mapkit.opendrive.locate import LaneLocator
    from twin.cli.main import cli as twin_cli

    _, out = lht_build
    runs = tmp_path / "run"
    result = CliRunner().invoke(twin_cli, ["drive", "--map", str(out), "--random", "--duration", "120",
                                           "--seed", "0", "-o", str(runs), "--no-plot", "--no-record"],
                                catch_exceptions=False)
    assert result.exit_code == 0, result.output
    metrics = json.loads((runs / "metrics.json").read_text())
    assert metrics["resets"] == 0 and metrics["distance_m"] > 500
    rows = list(csv.DictReader((runs / "trajectory.csv").open()))[::10]
    x, y, yaw = (np.array([float(row[key]) for row in rows]) for key in ("x", "y", "yaw"))
    speed = np.array([float(row["speed"]) for row in rows])
    odr = load_opendrive(out / "esmini.xodr")
    found = LaneLocator(odr, lane_types={"driving"}).locate(x, y)
    _, _, _, heading, *_ = odr.arrays.reference(found.road_index, found.s)
    # inside junctions connecting lanes overlap, so the lane found there need not be the one driven
    outside = ~np.array([odr.roads[int(road)].in_junction for road in found.road_index])
    moving = (speed > 1.0) & (found.distance < 0.5) & outside
    side = found.t * np.cos(yaw - heading)  # > 0: left of the reference line in the direction of travel
    assert moving.sum() > 50
    assert np.all(side[moving] > 0), np.flatnonzero(side[moving] <= 0)
    # no geoReference: lat/lon as CARLA places such a map, around 0 N 0 E
    lat = np.array([float(row["lat"]) for row in rows])
    assert np.all(np.abs(lat) < 0.01)


def test_traffic_needs_a_sumo_network(lht_build, tmp_path):
    from twin.cli.main import cli as twin_cli

    _, out = lht_build
    result = CliRunner().invoke(twin_cli, ["drive", "--map", str(out), "--random", "--duration", "5",
                                           "--traffic", "3", "-o", str(tmp_path / "run")])
    assert result.exit_code == 2
    lines = [line for line in result.output.splitlines() if line.startswith("Error")]
    assert lines == [f"Error: {out}: the build was made from an OpenDRIVE file and has no SUMO network, which "
                     "SUMO traffic (--traffic, --pedestrians, --demand) needs: build from OSM or a SUMO network "
                     "for traffic"]
    assert "Traceback" not in result.output


def test_unreadable_opendrive_input_is_one_line(tmp_path):
    broken = tmp_path / "broken.xodr"
    broken.write_text('<?xml version="1.0"?>\n<OpenDRIVE>\n  <header revMajor="1" revMinor="6"/>\n  <road id="1"',
                      encoding="utf-8")
    result = _mapkit("build", str(broken), "-o", str(tmp_path / "out"))
    assert result.exit_code == 2
    assert result.output.strip().splitlines()[-1].startswith(f"Error: {broken}:")
    assert "not well-formed XML" in result.output and "Traceback" not in result.output
    empty = tmp_path / "empty.xodr"
    empty.write_text('<?xml version="1.0"?>\n<OpenDRIVE><header revMajor="1" revMinor="6"/></OpenDRIVE>\n',
                     encoding="utf-8")
    result = _mapkit("build", str(empty), "-o", str(tmp_path / "out"))
    assert result.exit_code == 2
    assert result.output.strip().splitlines()[-1] == f"Error: {empty}: the OpenDRIVE file has no <road>"
    assert not (tmp_path / "out").exists()


def test_an_area_is_refused_for_opendrive_input(lht_build, tmp_path):
    source, _ = lht_build
    result = _mapkit("build", str(source), "-o", str(tmp_path / "out"), "--bbox", "0,0,0.001,0.001")
    assert result.exit_code == 2
    assert result.output.strip().splitlines()[-1] == (f"Error: {source}: an area (--bbox, --polygon, [area]) cuts "
                                                     "OSM or SUMO input; an OpenDRIVE input is built whole")
