"""Absurd numbers never reach an allocation: SUMO's invalid-position sentinel as a vertex, roads 5e9 or 5e12 m
long, coordinates of 1e12 m, lanes 1e12 m wide. Every command answers with one line naming file, line and road
and a non-zero exit code -- no traceback, no out-of-memory kill -- and the build's opendrive stage repairs
netconvert's sentinel vertices so the road keeps its real length."""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

import pytest
from click.testing import CliRunner

from tavf_mapkit.cli.main import cli
from tavf_mapkit.opendrive import load_opendrive, loads_opendrive
from tavf_mapkit.opendrive.plausibility import Extent
from tavf_mapkit.opendrive.repair import DROPPED_ROAD, DROPPED_VERTICES, repair_untrusted_geometry
from tests.xodr_factory import document, road_xml

ROAD_1 = road_xml('<geometry s="0" x="0" y="0" hdg="0" length="100"><line/></geometry>', 100.0, road_id="1")
ROAD_2 = road_xml('<geometry s="0" x="0" y="50" hdg="0" length="100"><line/></geometry>', 100.0, road_id="2")
VALID = document(ROAD_1, ROAD_2)
MEMORY_LIMIT = 2 * 1024 ** 3  # bytes of address space a command may use on these files

SPANS_50 = "the map's geometry spans 50 m, so no road can be longer than 100 km"
HOSTILE = {
    # name: (file text, the element whose line the message names, the message after "road N <element>: ")
    "length-5e12": (VALID.replace('id="1" length="100.0"', 'id="1" length="5.0e+12"'), '<road id="1"',
                    f"road 1 <road>: @length=5e+12 m is implausible: {SPANS_50}"),
    "length-5e9": (VALID.replace('id="1" length="100.0"', 'id="1" length="5.0e9"'), '<road id="1"',
                   f"road 1 <road>: @length=5e+09 m is implausible: {SPANS_50}"),
    "x-1e12": (VALID.replace('x="0" y="50"', 'x="1e12" y="50"'), 'x="1e12"',
               "road 2 <geometry>: x=1e+12, y=50 is not a place on Earth (|x| or |y| above 1e+08 m)"),
    "sentinel": (VALID.replace('x="0" y="50"', 'x="-1073741824.00000000" y="-1073741824.00000000"'), 'x="-107',
                 "road 2 <geometry>: x=-1073741824, y=-1073741824 is SUMO's invalid-position sentinel (-2^30 m): "
                 "netconvert could not compute this vertex"),
    "width-1e12": (VALID.replace('<width sOffset="0" a="3.5"', '<width sOffset="0" a="1e12"', 1), '<lane id="1"',
                   "road 1 <lane>: lane 1 width reaches 1e+12 m in the record at s=0; real roads stay below 1 km"),
    "nan": (VALID.replace('x="0" y="50"', 'x="NaN" y="50"'), 'x="NaN"',
            "road 2 <geometry>: @x='NaN' is not a finite number"),
}


def _line_of(text: str, needle: str) -> int:
    return next(number for number, line in enumerate(text.splitlines(), 1) if needle in line)


def _hostile(tmp_path, name: str) -> tuple[Path, str]:
    """The hostile file and the exact one-line error every command must give for it."""
    text, needle, message = HOSTILE[name]
    path = tmp_path / f"{name}.xodr"
    path.write_text(text)
    return path, f"Error: {path}:{_line_of(text, needle)}: {message}"


def _limit_memory() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, MEMORY_LIMIT))


def run_limited(module: str, *args: str, timeout: float = 120.0):
    """Run ``python -m module args`` with at most MEMORY_LIMIT of address space; (exit code, stdout, stderr,
    peak RSS in MiB). A regression then fails with a MemoryError instead of taking the machine's memory."""
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        process = subprocess.Popen([sys.executable, "-m", module, *args], stdout=out, stderr=err, env=env,
                                   preexec_fn=_limit_memory)
        timer = threading.Timer(timeout, process.kill)
        timer.start()
        try:
            _, status, usage = os.wait4(process.pid, 0)  # this child's own peak RSS, not the test run's
        finally:
            timer.cancel()
        process.returncode = os.waitstatus_to_exitcode(status)
        out.seek(0)
        err.seek(0)
        return process.returncode, out.read().decode(), err.read().decode(), usage.ru_maxrss / 1024


def _one_error_line(output: str) -> str:
    assert "Traceback" not in output
    errors = [line for line in output.splitlines() if line.startswith("Error: ")]
    assert len(errors) == 1, output
    return errors[0]


@pytest.mark.parametrize("name", ["length-5e12", "x-1e12", "sentinel", "width-1e12", "nan"])
@pytest.mark.parametrize("command", ["info", "export", "mesh"])
def test_absurd_numbers_give_one_line_in_every_reading_command(tmp_path, name, command):
    path, expected = _hostile(tmp_path, name)
    args = {"info": ["info", str(path)],
            "export": ["export", str(path), "--layer", "lane-border", "--crs", "local",
                       "-o", str(tmp_path / "out.csv")],
            "mesh": ["mesh", str(path), "-o", str(tmp_path / "mesh")]}[command]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 2, result.output
    assert result.output.strip() == expected


@pytest.mark.parametrize("name", ["length-5e12", "x-1e12", "sentinel", "width-1e12"])
def test_validate_reports_absurd_numbers_as_findings(tmp_path, name):
    path, expected = _hostile(tmp_path, name)
    result = CliRunner().invoke(cli, ["validate", str(path), "--json"])
    assert result.exit_code == 1 and "Traceback" not in result.output
    findings = json.loads(result.output)["findings"]
    plausible = [f for f in findings if f["rule"] == "geometry.plausible"]
    location, message = expected[len(f"Error: {path}:"):].split(": ", 1)
    road = message.split()[1]
    assert [(f["line"], f["road"], f["message"]) for f in plausible] == [
        (int(location), road, message.split(": ", 1)[1])]
    # the other rules still ran: every other error is the length mismatch, or why a rule could not sample
    assert all(f["rule"] == "geometry.length" or f["message"].startswith("not checked: ") for f in findings
               if f["severity"] == "error" and f["rule"] != "geometry.plausible")
    assert any(f["rule"] == "topology.dead-end" for f in findings)


@pytest.mark.slow
@pytest.mark.parametrize("command", ["info", "export", "validate", "mesh", "build", "twin"])
def test_5e9_m_road_is_refused_in_one_line_within_2_gb(tmp_path, command):
    """5e9 m at 0.5 m is 1e10 samples: before the budget, `mapkit info` grew past 23 GB."""
    path, expected = _hostile(tmp_path, "length-5e9")
    if command == "twin":
        build = tmp_path / "build"
        build.mkdir()
        (build / "hostile.xodr").write_bytes(path.read_bytes())
        (build / "manifest.json").write_text(json.dumps({"name": "hostile",
                                                         "artifacts": {"xodr": {"path": "hostile.xodr"}}}))
        expected = expected.replace(str(path), str(build / "hostile.xodr"))
        code, out, err, peak = run_limited("twin.cli.main", "drive", "--map", str(build), "--random",
                                           "--duration", "10", "-o", str(tmp_path / "run"))
    else:
        args = {"info": ["info"],
                "export": ["export", "--layer", "lane-center", "--crs", "local", "-o", str(tmp_path / "c.csv")],
                "validate": ["validate"], "mesh": ["mesh", "-o", str(tmp_path / "mesh")],
                "build": ["build", "-q", "-o", str(tmp_path / "b")]}[command]
        if command == "build":
            expected = expected.replace(f"Error: {path}", f"Error: {path.resolve()}")
        code, out, err, peak = run_limited("tavf_mapkit.cli.main", *args[:1], str(path), *args[1:])
    assert peak < 2048
    if command == "validate":  # findings on stdout, exit code 1
        assert code == 1 and "Traceback" not in out + err
        assert f"road 1: @length=5e+09 m is implausible: {SPANS_50}" in out
        return
    assert code == 2, err
    assert _one_error_line(out + err) == expected


def test_a_tiny_step_on_a_long_road_is_refused_before_allocating(tmp_path):
    long_road = road_xml('<geometry s="0" x="0" y="0" hdg="0" length="20000"><line/></geometry>', 20000.0)
    path = tmp_path / "long.xodr"
    path.write_text(document(long_road))
    code, out, err, peak = run_limited("tavf_mapkit.cli.main", "export", str(path), "--layer", "lane-border",
                                       "--step", "0.001", "--crs", "local", "-o", str(tmp_path / "out.csv"))
    assert code == 2 and peak < 2048
    line = _line_of(path.read_text(), '<road id="1"')
    assert _one_error_line(out + err) == (
        f"Error: {path}:{line}: road 1: sampling every 0.001 m would allocate 2e+07 points, more than the budget "
        "of 4e+06 (2e+07 of them on this road)")


def test_a_dash_of_a_nanometre_is_refused_by_the_mesher(tmp_path):
    marks = ('<roadMark sOffset="0" type="broken" color="standard"><type name="nano">'
             '<line length="1e-9" space="1e-9" tOffset="0" sOffset="0" width="0.12"/></type></roadMark>')
    lanes = f"""<laneSection s="0"><center><lane id="0" type="none">{marks}</lane></center><right>
        <lane id="-1" type="driving"><width sOffset="0" a="3" b="0" c="0" d="0"/></lane></right></laneSection>"""
    text = document(road_xml('<geometry s="0" x="0" y="0" hdg="0" length="100"><line/></geometry>', 100.0,
                             lanes=lanes))
    path = tmp_path / "dashes.xodr"
    path.write_text(text)
    result = CliRunner().invoke(cli, ["mesh", str(path), "-o", str(tmp_path / "mesh")])
    assert result.exit_code == 2 and "Traceback" not in result.output
    assert result.output.strip() == (
        f"Error: {path}:{_line_of(text, '<road id=')}: road 1: road-mark dashes would allocate 5e+10 points, more "
        "than the budget of 4e+06 (5e+10 of them on this road)")


# --- repair of netconvert's output ---------------------------------------------------------------------------

SENTINEL = "-1073741824.00000000"
#: road 7 as netconvert wrote road 19994 of Andorra: a line from (100, 50) to the sentinel, one back, and a
#: last line of 1e-8 m; the road really runs 12.5 m south, and its elevation record sits at the detour's middle
NETCONVERT_ROAD = road_xml(
    f'<geometry s="0" x="100" y="50" hdg="-2.35620169" length="1518499888.95381594"><line/></geometry>'
    f'<geometry s="1518499888.95381594" x="{SENTINEL}" y="{SENTINEL}" hdg="0.78539096" length="1518499901.44"><line/>'
    f'</geometry><geometry s="3036999790.39381594" x="100" y="37.5" hdg="0" length="0.00000001"><line/></geometry>',
    3036999790.39381595, road_id="7",
    link='<link><predecessor elementType="road" elementId="1" contactPoint="end"/>'
         '<successor elementType="road" elementId="2" contactPoint="start"/></link>',
    extra='<elevationProfile><elevation s="0" a="1" b="0" c="0" d="0"/>'
          '<elevation s="1518499888.95381594" a="2" b="0" c="0" d="0"/></elevationProfile>')


def test_sentinel_vertex_is_dropped_and_the_road_keeps_its_real_length():
    odr = loads_opendrive(document(ROAD_1, ROAD_2, NETCONVERT_ROAD), "netconvert.xodr")
    repaired, repairs = repair_untrusted_geometry(odr)
    assert [(r.action, r.road) for r in repairs] == [(DROPPED_VERTICES, "7")]
    assert str(repairs[0]).endswith(
        "road 7: dropped 1 of 4 reference-line vertices (x=-1073741824, y=-1073741824 is SUMO's invalid-position "
        "sentinel (-2^30 m): netconvert could not compute this vertex); @length 3.037e+09 -> 12.5 m")
    road = repaired.road_by_id["7"]
    assert road.length == pytest.approx(12.5, abs=1e-6)  # (+ the last line of 1e-8 m, below float resolution at 3e9)
    first, last = road.reference_line.geometries
    assert (first.x, first.y, first.length) == (100.0, 50.0, pytest.approx(12.5))
    assert (last.s, last.x, last.y) == (pytest.approx(12.5), 100.0, 37.5)
    x, y, _, _ = road.reference_line.evaluate([0.0, 6.25, road.length])
    assert x == pytest.approx([100.0, 100.0, 100.0]) and y == pytest.approx([50.0, 43.75, 37.5])
    # records along s move with the road: the one at the dropped vertex lands between its trusted neighbours
    assert 0.0 < road.elevation.s0[1] < 12.5 and road.lane_sections[0].s0 == 0.0
    assert road.predecessor.element_id == "1" and road.successor.element_id == "2"
    assert not repaired.arrays.budget.problems
    assert repaired.road_by_id["1"] is odr.road_by_id["1"]  # untouched roads are the same objects


def test_roads_beyond_repair_are_dropped_with_their_links():
    lost = road_xml(f'<geometry s="0" x="{SENTINEL}" y="{SENTINEL}" hdg="0" length="10"><line/></geometry>', 10.0,
                    road_id="8")
    far = road_xml('<geometry s="0" x="50000" y="0" hdg="0" length="10"><line/></geometry>', 10.0, road_id="9")
    linked = ROAD_1.replace("<planView>", '<link><successor elementType="road" elementId="8" contactPoint="start"/>'
                                          '</link><planView>')
    junction = ('<junction id="100"><connection id="0" incomingRoad="2" connectingRoad="8" contactPoint="start">'
                '<laneLink from="-1" to="-1"/></connection></junction>')
    odr = loads_opendrive(document(linked, ROAD_2, lost, far, tail=junction))
    repaired, repairs = repair_untrusted_geometry(odr, Extent(0.0, 0.0, 100.0, 50.0))
    assert [(r.action, r.road) for r in repairs] == [(DROPPED_ROAD, "8"), (DROPPED_ROAD, "9")]
    assert repairs[1].detail == "dropped the road: x=50000, y=0 lies far outside the input's extent"
    assert [road.id for road in repaired.roads] == ["1", "2"]
    assert repaired.road_by_id["1"].successor is None and repaired.junctions[0].connections == ()


def _run_opendrive_stage(folder: Path, date: str):
    """The stage as a build runs it, on a netconvert-like file (stamped with ``date``) beside a SUMO network."""
    from tavf_mapkit.pipeline.config import PipelineConfig
    from tavf_mapkit.pipeline.context import BuildContext
    from tavf_mapkit.pipeline.stages import get_stage

    folder.mkdir()
    xodr = folder / "net.xodr"
    xodr.write_text(document(ROAD_1, ROAD_2, NETCONVERT_ROAD).replace("<header ", f'<header date="{date}" '))
    net = folder / "net.net.xml"
    net.write_text('<net><location netOffset="0.00,0.00" convBoundary="0.00,0.00,200.00,50.00" '
                   'origBoundary="0,0,1,1" projParameter="!"/></net>')
    context = BuildContext(name="net", folder=folder, input_path=folder / "in.osm", input_kind="osm",
                           config=PipelineConfig(), artifacts={"xodr": xodr, "net": net})
    return xodr, get_stage("opendrive").run(context)


def test_opendrive_stage_repairs_netconvert_output_and_counts_it(tmp_path):
    xodr, output = _run_opendrive_stage(tmp_path / "build", "Mon Nov 23 18:28:43 2026")
    assert output.facts["repairs"] == {"dropped vertices": {"count": 1, "roads": ["7"]}}
    assert output.files["xodr"] == "net.xodr" and output.facts["roads"] == 3
    # the repaired file depends on the input only (not on netconvert's time stamp): later stages are reused
    again, _ = _run_opendrive_stage(tmp_path / "rebuild", "Mon Nov 23 19:04:10 2026")
    assert again.read_bytes() == xodr.read_bytes()
    rewritten = load_opendrive(xodr)
    assert rewritten.road_by_id["7"].length == pytest.approx(12.5, abs=1e-6)
    assert SENTINEL.split(".")[0] not in xodr.read_text()
    result = CliRunner().invoke(cli, ["info", "--json", str(xodr)])
    assert result.exit_code == 0 and json.loads(result.output)["total_length_m"] == pytest.approx(212.5, abs=1e-6)


def test_opendrive_stage_lets_netconvert_s_map_go_before_writing_the_repaired_one(tmp_path, monkeypatch):
    """The unrepaired map is not held while the curves are repaired, nor while the repaired map is written and
    summarised (on a city whose curves became arcs the two together took 1 GB more than the repaired map alone;
    its map-wide tables 250 MB while the curves were fitted)."""
    import gc
    import weakref

    from tavf_mapkit.opendrive import repair_curves as curves_module
    from tavf_mapkit.opendrive import writer
    from tavf_mapkit.pipeline.context import BuildContext

    loaded, alive_when_written, alive_when_curves = [], [], []
    load, write, curves = BuildContext.opendrive, writer.write_opendrive, curves_module.repair_curves

    def watch_and_repair_curves(odr, **options):
        gc.collect()
        alive_when_curves.append(loaded[0]() is not None)
        return curves(odr, **options)

    def load_and_watch(context):
        odr = load(context)
        loaded.append(weakref.ref(odr))
        return odr

    def watch_and_write(odr, path):
        gc.collect()
        alive_when_written.append(loaded[0]() is not None)
        write(odr, path)

    monkeypatch.setattr(BuildContext, "opendrive", load_and_watch)
    monkeypatch.setattr(writer, "write_opendrive", watch_and_write)
    monkeypatch.setattr(curves_module, "repair_curves", watch_and_repair_curves)
    xodr, output = _run_opendrive_stage(tmp_path / "build", "Mon Nov 23 18:28:43 2026")
    assert output.facts["repairs"] and alive_when_written == [False] and alive_when_curves == [False]
    assert load_opendrive(xodr).road_by_id["7"].length == pytest.approx(12.5, abs=1e-6)


def test_reference_network_with_absurd_shapes_is_refused_in_one_line(tmp_path, sample_build_dir):
    """`mapkit compare` resamples the reference network's lane shapes: they are checked like a map's geometry."""
    import re

    xodr, net = sample_build_dir / "sample.xodr", (sample_build_dir / "sample.net.xml").read_text()
    lane = re.search(r'<lane id="([^"]+)"[^>]* shape="([^" ]+) ', net)
    cases = {"1e12,0": "@shape vertex x=1e+12, y=0 is not a place on Earth (|x| or |y| above 1e+08 m)",
             "a,b": "@shape is not a list of x,y numbers"}
    for vertex, message in cases.items():
        hostile = tmp_path / "hostile.net.xml"
        text = net[:lane.start(2)] + vertex + net[lane.end(2):]
        hostile.write_text(text)
        result = CliRunner().invoke(cli, ["compare", str(xodr), str(hostile)])
        assert result.exit_code == 2 and "Traceback" not in result.output
        line = text[:lane.start()].count("\n") + 1
        assert result.output.strip() == f"Error: {hostile}:{line}: <lane>: lane {lane.group(1)}: {message}"
