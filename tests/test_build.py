"""`mapkit build`: the build folder, manifest, incremental reuse, atomicity under failure and interruption."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pyproj
import pytest
from click.testing import CliRunner

from tavf_mapkit.cli.main import cli
from tavf_mapkit.pipeline.stages import Stage, StageOutput, register_stage, unregister_stage
from tavf_mapkit.projection import proj_parameters

REPO = Path(__file__).resolve().parents[1]
SAMPLE = REPO / "sample_data" / "tavf_synthetic.osm"
JUNGFERNSTIEG = ("hamburg", "jungfernstieg_osm", "jungfernstieg_2023-03-10.osm")
TAVF_NET = ("hamburg", "tavf_dlr_sumo_net", "network.net.xml.gz")


def build(*args) -> object:
    return CliRunner().invoke(cli, ["build", *map(str, args)])


def manifest(folder: Path) -> dict:
    return json.loads((folder / "manifest.json").read_text())


def statuses(folder: Path) -> dict[str, str]:
    return {record["name"]: record["status"] for record in manifest(folder)["stages"]}


def reused(folder: Path) -> bool:
    """Every stage of the build reused: netconvert's OpenDRIVE has a place of its own (netconvert/NAME.xodr), so
    the repaired NAME.xodr does not make a rebuild run netconvert and the repairs again."""
    return all(status in ("unchanged", "unavailable") for status in statuses(folder).values())


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` with its bytes: equal snapshots mean byte-identical folders."""
    return {str(path.relative_to(folder)): path.read_bytes()
            for path in sorted(folder.rglob("*")) if path.is_file()}


def leftovers(parent: Path) -> list[str]:
    return sorted(p.name for p in parent.iterdir() if ".staging-" in p.name)


def assert_georeference_usable(folder: Path) -> dict:
    georeference = manifest(folder)["georeference"]
    pyproj.CRS.from_user_input(georeference["proj"])
    parameters = proj_parameters(georeference["proj"])
    assert "lat_0" in parameters and "lon_0" in parameters
    assert georeference["crs_valid"]
    assert georeference["lat_0"] is not None and georeference["lon_0"] is not None
    return georeference


@pytest.fixture(scope="module")
def sample_build(tmp_path_factory) -> Path:
    """One build of the sample shared by the read-only tests (copy it before changing it)."""
    folder = tmp_path_factory.mktemp("shared") / "sample"
    result = build(SAMPLE, "-o", folder, "-q")
    assert result.exit_code == 0, result.output
    return folder


@pytest.fixture
def existing_build(tmp_path) -> Path:
    folder = tmp_path / "build" / "sample"
    result = build(SAMPLE, "-o", folder, "-q")
    assert result.exit_code == 0, result.output
    return folder


@pytest.fixture
def temporary_stage():
    names = []

    def register(name: str, run, inputs=("xodr",)):
        cls = type(f"Test_{name}", (Stage,), {"inputs": inputs, "run": lambda self, context: run(context)})
        register_stage(name)(cls)
        names.append(name)

    yield register
    for name in names:
        unregister_stage(name)


def pipeline_file(folder: Path, stages: list[str], extra: str = "") -> Path:
    path = folder / "test-pipeline.toml"
    path.write_text(f"[pipeline]\nstages = {json.dumps(stages)}\n{extra}")
    return path


# --- the folder and its manifest ----------------------------------------------------------------------


def test_sample_build_has_the_documented_layout(sample_build):
    name = sample_build.name
    for relative in (f"{name}.xodr", f"{name}.net.xml", f"source/{name}.osm", "report/summary.json",
                     "report/summary.txt", "logs/netconvert.log", "manifest.json", "mesh/mesh.json",
                     "mesh/labelled/index.json", "report/mesh_preview.png", "collision/world.json"):
        assert (sample_build / relative).is_file(), relative
    assert not leftovers(sample_build.parent)


def test_manifest_records_inputs_tools_options_stages_and_attribution(sample_build):
    data = manifest(sample_build)
    assert data["input"]["kind"] == "osm"
    assert len(data["input"]["sha256"]) == 64 and data["input"]["bytes"] == SAMPLE.stat().st_size
    assert data["tools"]["netconvert"].startswith("Eclipse SUMO netconvert")
    assert data["tools"]["packages"]["osmium"] and data["tools"]["packages"]["eclipse-sumo"]
    assert data["attribution"] == "(c) OpenStreetMap contributors, ODbL 1.0"
    stages = {record["name"]: record for record in data["stages"]}
    assert [record["name"] for record in data["stages"]] == [
        "extract", "netconvert", "opendrive", "mesh", "collision", "check", "report"]
    netconvert = stages["netconvert"]
    assert netconvert["status"] == "ran" and netconvert["seconds"] > 0
    assert netconvert["options"]["profile"] == "carla" and netconvert["options"]["crs"] == "tmerc"
    assert set(netconvert["outputs"]) == {"net", "xodr", "netconvert_log"}
    assert netconvert["inputs"]["source"] == stages["extract"]["outputs"]["source"]["sha256"]
    assert all(record["status"] == "ran" for record in data["stages"]), [r["status"] for r in data["stages"]]
    # the opendrive stage repairs netconvert's file (its paramPoly3 @length, docs/build-folder.md): the mesh is made
    # from the repaired NAME.xodr
    assert stages["opendrive"]["facts"]["repairs"]["geometry length"]["count"] > 0
    assert stages["mesh"]["inputs"]["xodr"] == stages["opendrive"]["outputs"]["xodr"]["sha256"] == \
        data["artifacts"]["xodr"]["sha256"] != netconvert["outputs"]["xodr"]["sha256"]
    assert stages["collision"]["inputs"]["mesh"] == stages["mesh"]["outputs"]["mesh"]["sha256"]
    assert_georeference_usable(sample_build)


def test_report_summarises_the_build(sample_build):
    report = json.loads((sample_build / "report" / "summary.json").read_text())
    assert report["osm"]["traffic_signals"] == 2 and report["osm"]["buildings"] == 8
    assert report["opendrive"]["roads"] > 0 and report["sumo_net"]["traffic_lights"] == 1
    assert report["netconvert"]["warnings"] == 0
    assert report["georeference"]["proj"].startswith("+proj=tmerc +lat_0=53.556 +lon_0=9.975")


def test_human_summary_and_progress_lines(tmp_path):
    result = build(SAMPLE, "-o", tmp_path / "s")
    assert result.exit_code == 0
    assert "[2/7] netconvert: ran in" in result.stderr
    assert "[4/7] mesh: ran in" in result.stderr and "[5/7] collision: ran in" in result.stderr
    assert "xodr    s.xodr:" in result.stdout and "(c) OpenStreetMap contributors" in result.stdout
    assert len(result.stdout.splitlines()) < 25  # one screen


def test_json_output(tmp_path):
    result = build(SAMPLE, "-o", tmp_path / "s", "--json", "-q")
    assert result.exit_code == 0
    data = json.loads(result.stdout)
    assert data["status"] == "ok" and Path(data["outputs"]["xodr"]).is_file()
    assert data["report"]["osm"]["ways"] == 28


# --- incremental --------------------------------------------------------------------------------------


def test_rebuild_of_unchanged_input_reuses_every_stage(existing_build):
    before = manifest(existing_build)
    result = build(SAMPLE, "-o", existing_build, "-q")
    assert result.exit_code == 0
    assert reused(existing_build), statuses(existing_build)
    after = manifest(existing_build)
    assert after["artifacts"] == before["artifacts"]  # same outputs, byte for byte (sha256)
    name = existing_build.name
    assert (existing_build / f"{name}.xodr").is_file() and (existing_build / "netconvert" / f"{name}.xodr").is_file()


def test_force_reruns_every_stage(existing_build):
    assert build(SAMPLE, "-o", existing_build, "-q", "--force").exit_code == 0
    assert {status for status in statuses(existing_build).values()} == {"ran"}


def test_changing_an_option_reruns_only_what_depends_on_it(existing_build):
    assert build(SAMPLE, "-o", existing_build, "-q", "--profile", "full").exit_code == 0
    status = statuses(existing_build)
    assert status["extract"] == "unchanged" and status["netconvert"] == "ran" and status["report"] == "ran"


def test_changing_the_input_reruns_from_the_first_stage(existing_build, tmp_path):
    changed = tmp_path / "sample.osm"
    changed.write_text(SAMPLE.read_text().replace('name" v="Brückenweg"', 'name" v="Neue Brücke"'))
    assert build(changed, "-o", existing_build, "-q").exit_code == 0
    assert statuses(existing_build)["extract"] == "ran"


def test_a_new_stage_plugs_in_without_touching_the_runner(tmp_path, temporary_stage):
    def count_roads(context):
        text = context.artifacts["xodr"].read_text()
        context.output_path("extra/roads.txt").write_text(str(text.count("<road ")))
        return StageOutput(files={"road_count": "extra/roads.txt"}, facts={"roads": text.count("<road ")})

    temporary_stage("count", count_roads)
    pipeline = pipeline_file(tmp_path, ["extract", "netconvert", "count", "not_installed", "report"])
    folder = tmp_path / "s"
    assert build(SAMPLE, "--pipeline", pipeline, "-o", folder, "-q").exit_code == 0
    assert statuses(folder) == {"extract": "ran", "netconvert": "ran", "count": "ran", "not_installed": "unavailable",
                                "report": "ran"}
    assert int((folder / "extra" / "roads.txt").read_text()) > 0
    assert build(SAMPLE, "--pipeline", pipeline, "-o", folder, "-q").exit_code == 0
    assert statuses(folder)["count"] == "unchanged" and (folder / "extra" / "roads.txt").is_file()


def test_a_stage_whose_input_nobody_made_is_skipped_with_a_note(tmp_path, temporary_stage):
    temporary_stage("needs_mesh", lambda context: StageOutput(), inputs=("mesh",))
    pipeline = pipeline_file(tmp_path, ["extract", "netconvert", "needs_mesh", "report"])
    result = build(SAMPLE, "--pipeline", pipeline, "-o", tmp_path / "s")
    assert result.exit_code == 0
    assert "needs_mesh: skipped, needs mesh" in result.stderr
    assert statuses(tmp_path / "s")["needs_mesh"] == "skipped"


# --- atomic -------------------------------------------------------------------------------------------


def test_an_interrupt_during_a_stage_leaves_the_existing_build_byte_identical(existing_build,
                                                                              temporary_stage):
    def interrupt(context):
        (context.folder / "half-written.bin").write_bytes(b"\0" * 1000)
        raise KeyboardInterrupt

    temporary_stage("interrupt", interrupt)
    before = snapshot(existing_build)
    pipeline = pipeline_file(existing_build.parent, ["extract", "netconvert", "interrupt", "report"])
    result = build(SAMPLE, "--pipeline", pipeline, "-o", existing_build, "--force", "-q")
    assert result.exit_code == 130 and "Interrupted" in result.stderr
    assert snapshot(existing_build) == before
    assert not leftovers(existing_build.parent)


def test_a_failing_stage_leaves_the_existing_build_byte_identical(existing_build, temporary_stage):
    from tavf_mapkit.errors import StageError

    def fail(context):
        context.log_path("failing").write_text("what went wrong\n")
        raise StageError("simulated failure")

    temporary_stage("failing", fail)
    before = snapshot(existing_build)
    pipeline = pipeline_file(existing_build.parent, ["extract", "netconvert", "failing", "report"])
    result = build(SAMPLE, "--pipeline", pipeline, "-o", existing_build, "-q")
    assert result.exit_code == 1
    assert "simulated failure" in result.stderr and len(result.stderr.strip().splitlines()) == 1
    assert snapshot(existing_build) == before and not leftovers(existing_build.parent)
    kept_log = existing_build.parent / "sample.failed-failing.log"
    assert kept_log.read_text() == "what went wrong\n" and str(kept_log) in result.stderr


def test_a_netconvert_failure_is_a_clear_message_and_exit_code_1(existing_build, tmp_path):
    profile = tmp_path / "broken.toml"
    profile.write_text('extends = "carla"\n[osm]\n"no-such.option" = true\n')
    before = snapshot(existing_build)
    result = build(SAMPLE, "-o", existing_build, "--profile", profile)
    assert result.exit_code == 1
    error = result.stderr.strip().splitlines()[-1]
    assert error.startswith(f"Error: {SAMPLE}: netconvert: On processing option '--no-such.option=true'")
    assert "Traceback" not in result.output
    assert snapshot(existing_build) == before
    assert "No option with the name" in (existing_build.parent / "sample.failed-netconvert.log").read_text()


SIGTERM_SCRIPT = textwrap.dedent("""
    import sys, time
    from pathlib import Path
    from tavf_mapkit.cli.main import cli
    from tavf_mapkit.pipeline.stages import Stage, StageOutput, register_stage

    MARKER = Path(sys.argv[1])

    @register_stage("slow")
    class Slow(Stage):
        inputs = ("xodr",)
        def run(self, context):
            (context.folder / "partial.bin").write_bytes(b"x" * 1000)
            MARKER.write_text("started")
            time.sleep(60)
            return StageOutput()

    sys.argv = ["mapkit", *sys.argv[2:]]
    cli()
""")


def test_sigterm_during_a_stage_leaves_the_existing_build_byte_identical(existing_build, tmp_path):
    script, marker = tmp_path / "slow_build.py", tmp_path / "started"
    script.write_text(SIGTERM_SCRIPT)
    pipeline = pipeline_file(tmp_path, ["extract", "netconvert", "slow", "report"])
    before = snapshot(existing_build)
    process = subprocess.Popen([sys.executable, str(script), str(marker), "build", str(SAMPLE), "--pipeline",
                                str(pipeline), "-o", str(existing_build), "--force", "-q"],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO)
    deadline = time.monotonic() + 30
    while not marker.exists() and time.monotonic() < deadline and process.poll() is None:
        time.sleep(0.02)
    assert marker.exists(), process.communicate()
    process.send_signal(signal.SIGTERM)
    _, stderr = process.communicate(timeout=30)
    assert process.returncode == 130 and "Traceback" not in stderr
    assert snapshot(existing_build) == before and not leftovers(existing_build.parent)


def test_a_killed_builds_staging_folder_is_cleaned_up_by_the_next_build(existing_build):
    stale = existing_build.parent / ".sample.staging-dead"
    stale.mkdir()
    (stale / "junk").write_text("left by a SIGKILLed build")
    result = build(SAMPLE, "-o", existing_build, "-q")
    assert result.exit_code == 0
    assert result.stderr == (f"note: recovered from an earlier build of {existing_build} that was killed: "
                             "removed its unfinished staging folder .sample.staging-dead\n")
    assert not stale.exists()


def start_mapkit(*args) -> subprocess.Popen:
    """A real `mapkit` process (what a user runs and may kill), not an in-process CliRunner call."""
    return subprocess.Popen([sys.executable, "-m", "tavf_mapkit.cli.main", *map(str, args)], cwd=REPO,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def wait_for_staging(parent: Path, process: subprocess.Popen, artifact: str) -> Path:
    """The running build's staging folder, once ``artifact`` is in it (the build is past that stage)."""
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and process.poll() is None:
        found = [folder for folder in parent.glob(".sample.staging-*") if (folder / artifact).exists()]
        if found:
            return found[0]
        time.sleep(0.02)
    raise AssertionError(f"no staging folder with {artifact}: {process.communicate()}")


def test_a_sigkilled_build_is_recovered_by_the_next_run_with_one_line(existing_build):
    import socket

    before = snapshot(existing_build)
    process = start_mapkit("build", SAMPLE, "-o", existing_build, "--force", "-q")
    staging = wait_for_staging(existing_build.parent, process, "sample.xodr")  # netconvert done, mesh next
    process.kill()
    assert process.wait(timeout=30) == -signal.SIGKILL
    lock = existing_build.parent / ".sample.lock"
    assert staging.is_dir() and json.loads(lock.read_text())["pid"] == process.pid  # what the kill left
    assert snapshot(existing_build) == before

    result = build(SAMPLE, "-o", existing_build, "-q")
    assert result.exit_code == 0, result.output
    (line,) = result.stderr.splitlines()
    assert line.startswith(f"note: recovered from an earlier build of {existing_build} that was killed "
                           f"(pid {process.pid} on {socket.gethostname()}, started ")
    assert line.endswith(f"): removed its unfinished staging folder {staging.name}")
    assert not leftovers(existing_build.parent) and lock.read_text() == ""
    assert reused(existing_build), statuses(existing_build)  # the old build, intact
    assert build(SAMPLE, "-o", existing_build, "-q").stderr == ""  # recovered once, not on every run


def test_a_live_concurrent_build_is_still_refused(tmp_path):
    import socket

    target = tmp_path / "sample"
    process = start_mapkit("build", SAMPLE, "-o", target, "-q")
    wait_for_staging(tmp_path, process, "source")
    result = build(SAMPLE, "-o", target, "-q")
    assert result.exit_code == 1
    assert result.stderr.startswith(f"Error: {target}: another mapkit build (pid {process.pid} on "
                                    f"{socket.gethostname()}, started ")
    assert result.stderr.endswith(") is writing this build folder\n") and len(result.stderr.splitlines()) == 1
    _, stderr = process.communicate(timeout=120)
    assert process.returncode == 0 and stderr == ""  # the refused build touched nothing of the live one
    assert all(status == "ran" for status in statuses(target).values()) and not leftovers(tmp_path)


# --- bad input and output -----------------------------------------------------------------------------


def test_an_unwritable_output_folder_is_exit_code_2(tmp_path):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    result = build(SAMPLE, "-o", blocker / "sub" / "sample")
    assert result.exit_code == 2 and "is not a folder" in result.stderr
    assert "Traceback" not in result.output


@pytest.mark.skipif(os.geteuid() == 0, reason="root can write into read-only folders")
def test_a_read_only_parent_folder_is_exit_code_2(tmp_path):
    parent = tmp_path / "ro"
    parent.mkdir()
    parent.chmod(0o555)
    try:
        result = build(SAMPLE, "-o", parent / "sample")
        assert result.exit_code == 2 and "cannot write" in result.stderr
    finally:
        parent.chmod(0o755)


def test_a_folder_that_is_not_a_build_is_never_replaced(tmp_path):
    precious = tmp_path / "documents"
    precious.mkdir()
    (precious / "thesis.tex").write_text("years of work")
    result = build(SAMPLE, "-o", precious)
    assert result.exit_code == 2 and "not a mapkit build folder" in result.stderr
    assert (precious / "thesis.tex").read_text() == "years of work"


def test_a_truncated_osm_input_is_exit_code_2(tmp_path):
    broken = tmp_path / "broken.osm"
    broken.write_bytes(SAMPLE.read_bytes()[:5000])
    result = build(broken, "-o", tmp_path / "b")
    assert result.exit_code == 2
    assert "not well-formed OSM XML" in result.stderr and str(broken) in result.stderr
    assert not (tmp_path / "b").exists() and not leftovers(tmp_path)


def test_missing_and_unknown_inputs_are_exit_code_2(tmp_path):
    assert build(tmp_path / "missing.osm", "-o", tmp_path / "b").exit_code == 2
    other = tmp_path / "input.csv"
    other.write_text("a,b\n")
    result = build(other, "-o", tmp_path / "b")
    assert result.exit_code == 2 and "unknown input type" in result.stderr


def test_a_sumo_net_with_a_doctype_is_refused(tmp_path):
    hostile = tmp_path / "hostile.net.xml"
    hostile.write_text('<?xml version="1.0"?>\n<!DOCTYPE net SYSTEM "file:///etc/passwd">\n'
                       '<net version="1.9"><location netOffset="0,0" convBoundary="0,0,1,1" '
                       'origBoundary="0,0,1,1" projParameter="!"/></net>\n')
    result = build(hostile, "-o", tmp_path / "b")
    assert result.exit_code == 2 and "DOCTYPE" in result.stderr


# --- pipeline files -----------------------------------------------------------------------------------


def test_pipeline_paths_are_relative_to_the_pipeline_file(tmp_path, monkeypatch):
    area = tmp_path / "areas" / "west.geojson"
    area.parent.mkdir()
    ring = [[9.970, 53.553], [9.976, 53.553], [9.976, 53.559], [9.970, 53.559], [9.970, 53.553]]
    area.write_text(json.dumps({"type": "Polygon", "coordinates": [ring]}))
    pipeline = pipeline_file(tmp_path, ["extract", "netconvert", "report"],
                             '[area]\npolygon_path = "areas/west.geojson"\n')
    monkeypatch.chdir(REPO)  # somewhere else than the pipeline file
    result = build(SAMPLE, "--pipeline", pipeline, "-o", tmp_path / "west", "-q")
    assert result.exit_code == 0, result.output
    data = manifest(tmp_path / "west")
    assert {"role": "area.polygon_path", "path": str(area)}.items() <= data["inputs"][-1].items()
    assert data["stages"][0]["facts"]["area"]["description"] == "polygon west.geojson"
    assert data["stages"][0]["facts"]["ways"] < 28


def test_tavf_pipeline_file_loads():
    from tavf_mapkit.pipeline.config import load_pipeline

    config = load_pipeline(REPO / "pipelines" / "tavf.toml")
    assert config.name == "tavf" and config.section("area")["bbox"] == [9.95, 53.543, 10.01, 53.570]
    assert config.section("mesh")["eps"] == 0.05
    check = config.section("check")
    assert check["reference_network_path"].name == "network.net.xml.gz"
    assert check["gnss_trace_path"] == (REPO.parent / "shared" / "data" / "hamburg" / "gnss_ride_b4" /
                                        "thomas.json").resolve()


def test_sample_data_regenerates_byte_identical(tmp_path):
    output = tmp_path / "again.osm"
    generator = REPO / "sample_data" / "make_sample.py"
    subprocess.run([sys.executable, str(generator), "-o", str(output)], check=True, capture_output=True)
    assert output.read_bytes() == SAMPLE.read_bytes()


# --- real data ----------------------------------------------------------------------------------------


@pytest.mark.slow
def test_build_of_real_jungfernstieg_osm(shared, tmp_path):
    folder = tmp_path / "jungfernstieg"
    result = build(shared(*JUNGFERNSTIEG), "-o", folder, "--profile", "full", "-q")
    assert result.exit_code == 0, result.output
    georeference = assert_georeference_usable(folder)
    assert 53.548 < georeference["lat_0"] < 53.558 and 9.985 < georeference["lon_0"] < 10.006
    report = json.loads((folder / "report" / "summary.json").read_text())
    assert report["osm"]["ways"] == 700 and report["opendrive"]["roads"] > 100
    assert manifest(folder)["attribution"] == "(c) OpenStreetMap contributors, ODbL 1.0"


@pytest.mark.slow
def test_build_of_real_tavf_sumo_net(shared, tmp_path):
    folder = tmp_path / "tavf-net"
    result = build(shared(*TAVF_NET), "-o", folder, "-q")
    assert result.exit_code == 0, result.output
    georeference = assert_georeference_usable(folder)
    assert 53.543 < georeference["lat_0"] < 53.570  # centred on the network
    assert (folder / "source" / "tavf-net.net.xml.gz").is_file()
    report = json.loads((folder / "report" / "summary.json").read_text())
    assert report["sumo_input"]["edges"] == 617 and report["sumo_net"]["traffic_lights"] == 43
    assert manifest(folder)["attribution"]  # the DLR network was built from OSM


@pytest.mark.slow
def test_build_with_the_tavf_pipeline(shared, tmp_path):
    folder = tmp_path / "tavf"
    result = build(shared(*JUNGFERNSTIEG), "--pipeline", REPO / "pipelines" / "tavf.toml", "-o", folder, "-q")
    assert result.exit_code == 0, result.output
    data = manifest(folder)
    assert data["pipeline"]["sections"]["netconvert"]["profile"] == "full"
    roles = {item["role"]: item for item in data["inputs"]}
    assert roles["check.gnss_trace_path"]["sha256"] and roles["check.reference_network_path"]["sha256"]
    assert_georeference_usable(folder)


def test_atomic_writes_get_the_usual_file_mode(tmp_path):
    """Files written beside-then-renamed are readable by others like any file (mkstemp alone gives 0600)."""
    from tavf_mapkit.fileutil import write_text_atomic

    target = tmp_path / "out.json"
    old = os.umask(0o022)
    try:
        write_text_atomic(target, "{}")
    finally:
        os.umask(old)
    assert target.stat().st_mode & 0o777 == 0o644


def test_collision_stage_reuses_the_mesh_stage_solids_exactly(sample_build, tmp_path):
    # the collision stage read mesh/labelled/ tile by tile; made from scratch, the world is the same
    from tavf_mapkit.opendrive import load_opendrive
    from tavf_mapkit.world import build_collision_world

    name = sample_build.name
    collision = next(record for record in manifest(sample_build)["stages"] if record["name"] == "collision")
    assert collision["facts"]["reused"] == ["surface", "solids"]
    origin = json.loads((sample_build / "mesh" / "mesh.json").read_text())["origin"]
    fresh = build_collision_world(load_opendrive(sample_build / f"{name}.xodr"), tmp_path, eps=0.05,
                                  osm_path=sample_build / "source" / f"{name}.osm", tile=100.0,
                                  origin=[origin["x"], origin["y"], origin["z"]])
    assert fresh == json.loads((sample_build / "collision" / "world.json").read_text())
    assert fresh["solids"]["building"] > 0 and fresh["solids"]["curb"] > 0
    for tile in sorted((tmp_path / "collision" / "tiles").iterdir()):
        assert tile.read_bytes() == (sample_build / "collision" / "tiles" / tile.name).read_bytes(), tile.name


@pytest.mark.parametrize("stage, option, toml, shown", [("collision", "eps", '"abc"', "'abc'"),
                                                        ("mesh", "tile", "-5", "-5"), ("collision", "tile", "inf", "inf"),
                                                        ("mesh", "eps", "true", "true")])
def test_bad_metre_options_are_one_line_errors(tmp_path, stage, option, toml, shown):
    pipeline = pipeline_file(tmp_path, ["extract", "netconvert", "opendrive", "mesh", "collision"],
                             f"[{stage}]\n{option} = {toml}\n")
    result = build(SAMPLE, "--pipeline", pipeline, "-o", tmp_path / "b", "-q")
    assert result.exit_code == 2
    assert result.stderr.strip().endswith(f"[{stage}] {option} must be a positive number of metres, not {shown}")
    assert not (tmp_path / "b").exists() and not leftovers(tmp_path)


def test_damaged_mesh_stage_files_are_made_again_not_trusted(sample_build, tmp_path):
    import shutil
    from types import SimpleNamespace

    from tavf_mapkit.pipeline.builtin.collision import _MeshStageOutput

    mesh = tmp_path / "mesh"
    shutil.copytree(sample_build / "mesh", mesh)
    meshed = _MeshStageOutput(SimpleNamespace(artifacts={"mesh": mesh}))
    osm = sample_build / "source" / f"{sample_build.name}.osm"
    assert meshed.labelled(0.05, 100.0, osm) == mesh / "labelled" and meshed.origin()
    assert meshed.labelled(0.1, 100.0, osm) is None  # other eps
    assert meshed.labelled(0.05, 50.0, osm) is None  # other tiles
    assert meshed.labelled(0.05, 100.0, None) is None  # made with buildings, wanted without
    tiles = sorted((mesh / "labelled").glob("tile_*.npz"))
    data = tiles[0].read_bytes()
    tiles[0].write_bytes(data[: len(data) // 2])
    assert meshed.labelled(0.05, 100.0, osm) is None
    tiles[0].write_bytes(data)
    tiles[-1].write_bytes(b"not a zip")
    assert meshed.labelled(0.05, 100.0, osm) is None
    assert meshed.labelled(0.05, 100.0, osm, read=False) == mesh / "labelled"  # there; the caller reads it
    tiles[-1].unlink()
    assert meshed.labelled(0.05, 100.0, osm) is None
    assert meshed.labelled(0.05, 100.0, osm, read=False) is None
    (mesh / "mesh.json").write_text("{")
    assert _MeshStageOutput(SimpleNamespace(artifacts={"mesh": mesh})).origin() is None


@pytest.mark.parametrize("damage", ["truncated", "not a zip"])
def test_collision_stage_meshes_anew_when_a_labelled_tile_is_damaged(sample_build, tmp_path, damage):
    # the stage reads each labelled tile once, while it builds; a damaged one is found then, the half-built world
    # is dropped and the stage meshes the map itself: the same world, nothing reused, no staging folder left
    import shutil

    from tavf_mapkit.pipeline.builtin.collision import CollisionStage
    from tavf_mapkit.pipeline.config import load_pipeline
    from tavf_mapkit.pipeline.context import BuildContext

    name = sample_build.name
    folder = tmp_path / name
    for part in ("mesh", "source"):
        shutil.copytree(sample_build / part, folder / part)
    shutil.copy(sample_build / f"{name}.xodr", folder / f"{name}.xodr")
    tiles = sorted((folder / "mesh" / "labelled").glob("tile_*.npz"))
    damaged = tiles[len(tiles) // 2]
    data = damaged.read_bytes()
    damaged.write_bytes(data[: len(data) // 2] if damage == "truncated" else b"not a zip")
    context = BuildContext(name=name, folder=folder, input_path=sample_build / "source" / f"{name}.osm",
                           input_kind="osm", config=load_pipeline(None),
                           artifacts={"xodr": folder / f"{name}.xodr", "mesh": folder / "mesh",
                                      "source": folder / "source" / f"{name}.osm"})
    facts = CollisionStage().run(context).facts
    assert facts["reused"] == []
    expected = sample_build / "collision"
    assert (folder / "collision" / "world.json").read_bytes() == (expected / "world.json").read_bytes()
    made = sorted(path.name for path in (folder / "collision" / "tiles").iterdir())
    assert made == sorted(path.name for path in (expected / "tiles").iterdir())
    for tile in made:
        assert (folder / "collision" / "tiles" / tile).read_bytes() == (expected / "tiles" / tile).read_bytes()
    assert sorted(path.name for path in folder.iterdir()) == ["collision", "mesh", f"{name}.xodr", "source"]
