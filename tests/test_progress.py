"""Progress of long build stages (tavf_mapkit/progress.py): one self-overwriting line on a terminal -- units
done of the total, elapsed, time left -- at most 4 renders a second; nothing with --json, -q or when stderr is
not a terminal; and the build's results are the same either way.

The terminal is a real pseudo-terminal (``pty``) in raw mode (no newline translation), so every carriage
return on it is one the build wrote."""

from __future__ import annotations

import fcntl
import io
import json
import os
import pty
import re
import struct
import subprocess
import sys
import termios
import threading
import tty
from pathlib import Path

import pytest

from tavf_mapkit.progress import ProgressLine, duration, format_progress, progress_line, reporter

REPO = Path(__file__).resolve().parents[1]
MAPKIT = Path(sys.executable).parent / "mapkit"
COLUMNS = 100
#: a rendered line with an estimate: "[4/7] mesh: 41/580 tiles (7%), 0:03 elapsed, about 0:02 left"
ESTIMATE = re.compile(r"^\[\d/\d\] (\w+): \d+/\d+ tiles \(\d+%\), \d+:\d\d elapsed, about \d+:\d\d left *$")


class FakeClock:
    def __init__(self):
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


# --- the line ----------------------------------------------------------------------------------------------


def test_the_line_says_units_done_elapsed_and_time_left():
    assert format_progress("[4/7] mesh", "tiles", 120, 480, 12.0, 12.0) == \
        "[4/7] mesh: 120/480 tiles (25%), 0:12 elapsed, about 0:36 left"
    # the estimate runs from the first report of this kind of unit; elapsed from the start of the stage
    assert format_progress("[4/7] mesh", "tiles", 1, 3, 70.0, 10.0) == \
        "[4/7] mesh: 1/3 tiles (33%), 1:10 elapsed, about 0:20 left"
    assert format_progress("[3/7] opendrive", "curves", 0, 9000, 2.0, 0.0) == \
        "[3/7] opendrive: 0/9000 curves (0%), 0:02 elapsed, estimating time left"
    assert format_progress("[5/7] collision", "tiles", 35, 35, 3.4, 3.0) == \
        "[5/7] collision: 35/35 tiles (100%), 0:03 elapsed"
    # rounded up: a stage with work left never says 0:00
    assert format_progress("[4/7] mesh", "tiles", 99, 100, 0.5, 0.5).endswith("about 0:01 left")
    assert duration(3600 + 62) == "1:01:02" and duration(59.6) == "1:00"


def test_renders_are_rate_limited_and_show_the_state_at_the_time():
    clock = FakeClock()
    stream = io.StringIO()
    line = ProgressLine(stream, clock=clock, columns=COLUMNS)
    report = line.task("[4/7] mesh")("tiles")
    for done in range(1000):  # 1000 tiles, one every millisecond: one second of work
        clock.now = done / 1000
        report(done, 1000)
    # at most one render per 0.25 s: at 0, 0.25, 0.5 and 0.75 s
    assert line.renders == 4
    renders = stream.getvalue().split("\r")[1:]
    assert [int(re.search(r"(\d+)/1000", text).group(1)) for text in renders] == [0, 250, 500, 750]
    # a new kind of unit is rate-limited with the rest
    clock.now = 0.9
    other = line.task("[5/7] collision")("tiles")
    other(0, 10)
    assert line.renders == 4
    clock.now = 1.0
    other(3, 10)
    assert line.renders == 5 and stream.getvalue().split("\r")[-1].startswith("[5/7] collision: 3/10 tiles")


def test_the_line_overwrites_itself_never_wraps_and_makes_room_for_lasting_lines():
    clock = FakeClock()
    stream = io.StringIO()
    line = ProgressLine(stream, clock=clock, columns=30)
    report = line.task("[4/7] mesh")("building groups")
    report(0, 12)
    first = stream.getvalue()
    assert first.startswith("\r") and len(first) == 1 + 29  # cut to the width, less one column
    clock.now += 1.0
    line.task("[5/7] x")("tiles")(1, 2)
    second = stream.getvalue()[len(first):]
    # a shorter line is padded with spaces over the longer one before it
    assert second.startswith("\r[5/7] x: 1/2 tiles") and len(second) == 1 + 29
    line.print("[5/7] x: ran in 1.00 s")
    third = stream.getvalue()[len(first) + len(second):]
    assert third == "\r" + " " * 29 + "\r" + "[5/7] x: ran in 1.00 s\n"
    line.clear()  # nothing live: nothing written
    assert stream.getvalue().endswith("ran in 1.00 s\n")


def test_only_a_terminal_without_quiet_or_json_gets_a_line(tmp_path):
    master, slave = pty.openpty()
    read, write = os.pipe()
    try:
        with open(slave, "w", closefd=False) as terminal, open(write, "w", closefd=False) as pipe, \
                open(tmp_path / "log.txt", "w") as log:
            assert isinstance(progress_line(terminal), ProgressLine)
            assert progress_line(terminal, quiet=True) is None
            assert progress_line(terminal, as_json=True) is None
            assert progress_line(pipe) is None
            assert progress_line(log) is None
            assert progress_line(io.StringIO()) is None
    finally:
        for fd in (master, slave, read, write):
            os.close(fd)


def test_work_nobody_watches_reports_to_nothing():
    report = reporter(None, "tiles")
    assert report(1, 2) is None


# --- a real build on a terminal and off it ------------------------------------------------------------------


def run_on_terminal(args: list, cwd: Path) -> tuple[int, str, str]:
    """(exit code, stdout, stderr) of ``mapkit ARGS``, stderr on a raw pseudo-terminal of COLUMNS columns."""
    master, slave = pty.openpty()
    tty.setraw(slave)  # no newline translation: every carriage return is the program's
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 40, COLUMNS, 0, 0))
    chunks: list[bytes] = []

    def pump() -> None:  # the terminal must be read while the build writes, or it blocks when full
        while True:
            try:
                data = os.read(master, 65536)
            except OSError:  # EIO: the program closed its end
                return
            if not data:
                return
            chunks.append(data)

    reader = threading.Thread(target=pump, daemon=True)
    try:
        process = subprocess.Popen([str(MAPKIT), *map(str, args)], cwd=cwd, stdin=subprocess.DEVNULL,
                                   stdout=subprocess.PIPE, stderr=slave)
        os.close(slave)
        slave = None
        reader.start()
        stdout, _ = process.communicate(timeout=600)
        reader.join(timeout=30)
    finally:
        if slave is not None:
            os.close(slave)
        os.close(master)
    return process.returncode, stdout.decode(), b"".join(chunks).decode()


@pytest.fixture(scope="module")
def region(tmp_path_factory) -> Path:
    """A synthetic region of 5 x 5 crossings (about 350 roads): stages long enough for renders 4 a second."""
    path = tmp_path_factory.mktemp("region") / "region.osm"
    generator = REPO / "sample_data" / "make_region.py"
    subprocess.run([sys.executable, str(generator), "--grid", "5", "-o", str(path)], check=True,
                   capture_output=True)
    return path


@pytest.fixture(scope="module")
def terminal_build(region, tmp_path_factory) -> tuple[Path, str]:
    folder = tmp_path_factory.mktemp("terminal") / "region"
    code, stdout, stderr = run_on_terminal(["build", region, "-o", folder], region.parent)
    assert code == 0, stderr
    return folder, stderr


@pytest.fixture(scope="module")
def piped_build(region, tmp_path_factory) -> tuple[Path, str]:
    folder = tmp_path_factory.mktemp("piped") / "region"  # same name: the same mesh.json and world.json
    result = subprocess.run([str(MAPKIT), "build", str(region), "-o", str(folder)], cwd=region.parent,
                            capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    return folder, result.stderr


def test_a_terminal_shows_tiles_done_and_time_left(terminal_build):
    _, stderr = terminal_build
    lines = stderr.split("\n")
    renders = [piece for line in lines for piece in line.split("\r") if "elapsed" in piece]
    assert any(ESTIMATE.match(text) for text in renders), renders
    assert all(len(text) < COLUMNS for text in renders)  # never wraps, or it could not be overwritten
    # every lasting line starts on a line of its own (the live one blanked before it) and the live line is
    # blanked at the end
    lasting = [line.split("\r")[-1] for line in lines[:-1]]
    assert any(text.startswith("[4/7] mesh: ran in") for text in lasting)
    assert not any("elapsed" in text for text in lasting)
    assert lines[-1].strip(" \r") == ""


def test_stderr_that_is_not_a_terminal_gets_no_progress_line(piped_build):
    _, stderr = piped_build
    assert "\r" not in stderr
    assert "[4/7] mesh: ran in" in stderr and "[5/7] collision: ran in" in stderr
    assert "elapsed" not in stderr


def test_results_are_the_same_with_and_without_progress(terminal_build, piped_build):
    watched, unwatched = (json.loads((folder / "manifest.json").read_text()) for folder, _ in
                          (terminal_build, piped_build))
    for artifact in ("xodr", "mesh", "mesh_preview", "collision"):
        assert watched["artifacts"][artifact] == unwatched["artifacts"][artifact], artifact


@pytest.fixture(scope="module")
def one_road(tmp_path_factory) -> tuple[Path, Path]:
    """(OpenDRIVE of one straight road, pipeline of the mesh stage alone): its one report renders at once."""
    sys.path.insert(0, str(Path(__file__).parent))
    from xodr_factory import document, road_xml

    folder = tmp_path_factory.mktemp("one-road")
    xodr, pipeline = folder / "one.xodr", folder / "mesh-only.toml"
    xodr.write_text(document(road_xml('<geometry s="0" x="0" y="0" hdg="0" length="300"><line/></geometry>',
                                      300.0)))
    pipeline.write_text('[pipeline]\nstages = ["mesh"]\n')
    return xodr, pipeline


@pytest.mark.parametrize("flag", [None, "--json", "-q"])
def test_json_and_quiet_show_no_progress_on_a_terminal(one_road, flag, tmp_path):
    """The first report of a stage renders at once (nothing rendered before it): without a flag the mesh stage
    of one road shows its line, with --json or -q it does not."""
    xodr, pipeline = one_road
    code, stdout, stderr = run_on_terminal(["build", xodr, "--pipeline", pipeline, "-o", tmp_path / "one",
                                            *([flag] if flag else [])], tmp_path)
    assert code == 0, stderr
    if flag is None:
        assert "\r[1/1] mesh: 0/1 roads (0%), " in stderr and "\n[1/1] mesh: ran in" in stderr
        return
    assert "\r" not in stderr and "elapsed" not in stderr
    if flag == "--json":
        assert json.loads(stdout)["status"] == "ok"
        assert "\n[1/1] mesh: ran in" in stderr  # the lasting lines stay
    else:
        assert stderr == ""
