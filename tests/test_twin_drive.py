"""``twin drive`` end to end on real builds: outputs, metrics contract, determinism, hooks, bad input."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from conftest import shared_path

from tavf_mapkit.opendrive import load_opendrive
from twin.cli.main import cli
from twin.session.config import DriveConfig
from twin.session.hooks import SessionHook
from twin.session.loop import Session

CONTRACT = ("sim_seconds", "wall_seconds", "real_time_factor", "resets", "collisions", "off_road_seconds",
            "lateral_error_mean_m")


def drive(*args):
    return CliRunner().invoke(cli, ["drive", *map(str, args)])


def rows(path: Path) -> list[dict]:
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


@pytest.fixture(scope="module")
def random_drive(sample_build_dir, tmp_path_factory):
    out = tmp_path_factory.mktemp("drive") / "random"
    result = drive("--map", sample_build_dir, "--random", "--duration", 60, "--seed", 4, "-o", out,
                   "--no-record", "--json")
    assert result.exit_code == 0, result.output
    return out, json.loads(result.output)


def test_random_drive_writes_the_outputs(random_drive):
    out, metrics = random_drive
    assert sorted(p.name for p in out.iterdir()) >= ["collisions.csv", "drive.png", "gnss.csv", "imu.csv",
                                                      "metrics.json", "trajectory.csv"]
    assert json.loads((out / "metrics.json").read_text()) == metrics
    assert all(key in metrics for key in CONTRACT)
    assert metrics["sim_seconds"] == 60.0 and metrics["steps"] == 1200
    assert metrics["resets"] == 0 and metrics["collisions"] == 0 and metrics["off_road_seconds"] == 0
    assert metrics["distance_m"] > 200  # it drove, at urban speeds
    trajectory = rows(out / "trajectory.csv")
    assert list(trajectory[0]) == ["t", "x", "y", "z", "yaw", "speed", "lat", "lon", "road", "lane"]
    assert len(trajectory) == 1201
    assert len(rows(out / "gnss.csv")) == 601  # 10 Hz
    assert not [p for p in out.parent.iterdir() if p.name.startswith(".")]  # no temporary folder left


def test_zero_noise_gnss_converts_back_onto_the_trajectory(random_drive, sample_build_dir):
    out, _ = random_drive
    from twin.sim.build import Build

    georef = load_opendrive(Build.open(sample_build_dir).xodr).georeference
    trajectory = {r["t"]: r for r in rows(out / "trajectory.csv")}
    fixes = rows(out / "gnss.csv")
    lat = np.array([float(f["lat"]) for f in fixes])
    lon = np.array([float(f["lon"]) for f in fixes])
    x, y = georef.wgs84_to_local(lon, lat)
    tx = np.array([float(trajectory[f["t"]]["x"]) for f in fixes])
    ty = np.array([float(trajectory[f["t"]]["y"]) for f in fixes])
    # 9 decimals of a degree are 0.1 mm; the trajectory keeps 4 decimals of a metre
    assert np.max(np.hypot(x - tx, y - ty)) <= 1e-3


def test_same_seed_gives_byte_identical_trajectories(sample_build_dir, tmp_path):
    outputs = []
    for name, seed in (("a", 9), ("b", 9), ("c", 10)):
        result = drive("--map", sample_build_dir, "--random", "--duration", 20, "--seed", seed, "--gnss-noise", 1.0,
                       "-o", tmp_path / name, "--no-record", "--no-plot")
        assert result.exit_code == 0, result.output
        outputs.append((tmp_path / name / "trajectory.csv").read_bytes() + (tmp_path / name / "gnss.csv").read_bytes())
    assert outputs[0] == outputs[1]
    assert outputs[0] != outputs[2]


def test_a_finer_step_drives_the_same_path(sample_build_dir, tmp_path):
    """--dt 0.025 against the default 0.05 with the PID controller: the controllers work in seconds, so the car
    follows the same line (within 5 cm), and a repeat at the finer step is byte-identical."""
    from shapely import LineString, Point

    paths, files = {}, {}
    for name, dt in (("a", 0.05), ("b", 0.025), ("c", 0.025)):
        result = drive("--map", sample_build_dir, "--random", "--duration", 60, "--seed", 3, "--controller", "pid",
                       "--dt", dt, "-o", tmp_path / name, "--no-record", "--no-plot")
        assert result.exit_code == 0, result.output
        files[name] = (tmp_path / name / "trajectory.csv").read_bytes()
        table = rows(tmp_path / name / "trajectory.csv")
        paths[name] = np.array([(float(r["x"]), float(r["y"])) for r in table])
    assert files["b"] == files["c"] and len(paths["b"]) == 2 * len(paths["a"]) - 1
    lines = LineString(paths["a"]), LineString(paths["b"])

    def off(points, line):
        """Distances of the points from the line, leaving out those beyond its end (one car may lead by a
        metre or so after a minute: the speed loop brakes and accelerates a step earlier or later)."""
        return [line.distance(Point(p)) for p in points if line.project(Point(p)) < line.length - 1e-3]

    apart = max(off(paths["a"], lines[1]) + off(paths["b"], lines[0]))
    assert apart < 0.05 and lines[0].length > 300.0
    assert abs(lines[0].length - lines[1].length) < 0.01 * lines[0].length


def test_pacing_holds_the_drive_to_its_rate_and_changes_nothing_else(sample_build_dir, tmp_path):
    """--pace 10: 3 simulated seconds take at least 0.3 s of wall time; the trajectory is the unpaced one."""
    outputs = []
    for name, pace in (("free", ()), ("paced", ("--pace", 10))):
        result = drive("--map", sample_build_dir, "--random", "--duration", 3, "--seed", 4, *pace,
                       "-o", tmp_path / name, "--no-record", "--no-plot")
        assert result.exit_code == 0, result.output
        outputs.append((tmp_path / name / "trajectory.csv").read_bytes())
    metrics = json.loads((tmp_path / "paced" / "metrics.json").read_text())
    assert metrics["real_time_factor"] <= 10.0 + 1e-6  # sleeping can only slow it down to the pace, never below
    assert outputs[0] == outputs[1]


class Probe(SessionHook):
    name = "probe"

    def __init__(self, fail_at: int | None = None, cap: float | None = None):
        self.frames, self.started, self.finished = [], False, None
        self.fail_at, self.cap = fail_at, cap

    def start(self, session):
        self.started = session.config["map_sha256"] == session.build.map_sha256 and session.out_dir.is_dir()

    def target_speed(self, session, t, speed):
        return self.cap if self.cap is not None else speed

    def after_step(self, session, frame):
        if frame.step == self.fail_at:
            raise RuntimeError("probe broke")
        self.frames.append(frame)

    def finish(self, session, metrics):
        self.finished = dict(metrics)
        metrics["probe_frames"] = len(self.frames)


def test_hooks_see_every_frame_and_a_failing_hook_is_logged_not_fatal(sample_build_dir, tmp_path, caplog):
    good, bad = Probe(), Probe(fail_at=5)
    config = DriveConfig(map=sample_build_dir, out=tmp_path / "out", random=True, duration=10.0, seed=1,
                         plot=False)
    metrics = Session(config, [bad, good]).run()
    assert good.started and [f.step for f in good.frames] == list(range(201))
    assert all(f.gnss is not None for f in good.frames[::2]) and good.frames[1].gnss is None
    assert [f.step for f in bad.frames] == [0, 1, 2, 3, 4]
    assert metrics["hook_errors"] == 1 and "probe broke" in metrics["hook_error_messages"][0]
    assert "hook probe failed in after_step at step 5" in caplog.text
    saved = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert saved["probe_frames"] == 201 and good.finished["sim_seconds"] == 10.0


def test_a_hook_can_stop_the_car(sample_build_dir, tmp_path):
    probe = Probe(cap=0.0)
    config = DriveConfig(map=sample_build_dir, out=tmp_path / "out", random=True, duration=10.0, plot=False)
    metrics = Session(config, [probe]).run()
    assert metrics["distance_m"] < 0.5 and metrics["resets"] == 0


def _one_line_error(result, *needles):
    assert result.exit_code == 2, result.output
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("Error:"), result.output
    assert "Traceback" not in result.output
    for needle in needles:
        assert needle in lines[0]


def test_a_plug_in_given_bad_input_stops_the_drive_with_one_line(sample_build_dir, tmp_path):
    """--traffic on a build without its SUMO network: the user asked for traffic, so no silent drive without."""
    import shutil

    build = tmp_path / "sample"
    shutil.copytree(sample_build_dir, build)
    (build / "sample.net.xml").unlink()
    result = drive("--map", build, "--random", "--duration", 2, "--traffic", 3, "-o", tmp_path / "o")
    _one_line_error(result, "sample.net.xml")
    assert not (tmp_path / "o").exists()


def test_bad_input_is_one_line_and_exit_2(sample_build_dir, tmp_path):
    _one_line_error(drive("--map", tmp_path, "--random", "-o", tmp_path / "o"), "not a build folder")
    _one_line_error(drive("--map", tmp_path / "missing", "--random", "-o", tmp_path / "o"), "not a build")
    empty = tmp_path / "empty.csv"
    empty.write_text("lat,lon,time\n")
    _one_line_error(drive("--map", sample_build_dir, "--route", empty, "-o", tmp_path / "o"), "empty.csv")
    far = tmp_path / "berlin.csv"
    far.write_text("lat,lon\n" + "".join(f"52.52{i},13.40{i}\n" for i in range(10)))
    _one_line_error(drive("--map", sample_build_dir, "--route", far, "-o", tmp_path / "o"), "outside the map")
    bag = tmp_path / "broken.bag"
    bag.write_bytes(b"#ROSBAG V2.0\n" + bytes(range(256)) * 4)
    _one_line_error(drive("--map", sample_build_dir, "--route", bag, "-o", tmp_path / "o"), "broken.bag")
    assert not (tmp_path / "o").exists()


def test_output_folder_that_is_not_ours_is_refused(sample_build_dir, tmp_path):
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "thesis.tex").write_text("keep me")
    _one_line_error(drive("--map", sample_build_dir, "--random", "--duration", 1, "-o", tmp_path / "mine"),
                    "not a twin drive output folder")
    assert (tmp_path / "mine" / "thesis.tex").read_text() == "keep me"


@pytest.mark.slow
def test_half_an_hour_of_random_routes_without_reset_or_off_road(sample_build_dir, tmp_path):
    result = drive("--map", sample_build_dir, "--random", "--duration", 1800, "--seed", 0, "-o", tmp_path / "o",
                   "--no-record", "--no-plot", "--json")
    assert result.exit_code == 0, result.output
    metrics = json.loads(result.output)
    assert metrics["sim_seconds"] == 1800.0 and metrics["distance_m"] > 10_000
    assert metrics["resets"] == 0 and metrics["off_road_seconds"] == 0.0 and metrics["collisions"] == 0


@pytest.mark.slow
def test_half_an_hour_on_the_tavf_build_never_meets_a_junction_curb(tavf_dlr_build, tmp_path):
    # netconvert's TAVF junctions have right turns tighter than the car turns; their curbs must leave room
    world = json.loads((tavf_dlr_build / "collision" / "world.json").read_text())
    assert world["solids"]["curb"] > 300  # the junction curbs are there
    result = drive("--map", tavf_dlr_build, "--random", "--duration", 1800, "--seed", 0, "-o", tmp_path / "o",
                   "--no-record", "--no-plot", "--json")
    assert result.exit_code == 0, result.output
    metrics = json.loads(result.output)
    assert metrics["distance_m"] > 10_000
    assert metrics["resets"] == 0 and metrics["collisions"] == 0 and metrics["off_road_seconds"] == 0.0


@pytest.mark.slow
def test_replaying_the_shared_ride_lands_on_the_recording(tavf_dlr_build, tmp_path):
    ride = shared_path("hamburg", "gnss_ride_b4", "thomas.json")
    result = drive("--map", tavf_dlr_build, "--route", ride, "-o", tmp_path / "o", "--no-record", "--no-plot",
                   "--json")
    assert result.exit_code == 0, result.output
    metrics = json.loads(result.output)
    assert metrics["trace_fixes"] == 587 and metrics["trace_fixes_matched"] > 400
    assert metrics["trace_distance_mean_m"] - metrics["trace_floor_mean_m"] <= 0.5
    assert metrics["route_completed"]


def test_drive_plot_samples_the_map_in_parts(sample_build_dir):
    """drive.png's lane centres, sampled a part of the map at a time (a region's at once are refused by the
    map's allocation budget), are the whole map's samples inside the plot, in the same order."""
    import numpy as np

    from tavf_mapkit.opendrive import load_opendrive
    from tavf_mapkit.opendrive.sampling import sample_lanes
    from twin.session.plot import lane_centres_in

    odr = load_opendrive(sample_build_dir / "sample.xodr")
    whole = sample_lanes(odr, 2.0)
    centre = whole.center_points(with_height=False)
    box = (-150.0, -120.0, 200.0, 90.0)
    inside = (centre[:, 0] > box[0]) & (centre[:, 0] < box[2]) & (centre[:, 1] > box[1]) & (centre[:, 1] < box[3])
    assert 0 < inside.sum() < len(centre)
    parts, driving = lane_centres_in(odr, *box, chunk_points=500)
    np.testing.assert_array_equal(parts, centre[inside])
    np.testing.assert_array_equal(driving, whole.lane_type[inside] == "driving")
