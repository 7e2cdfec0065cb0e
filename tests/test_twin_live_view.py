"""`twin drive --view`: a real drive with SUMO traffic on the sample build, its live view server polled over
HTTP on loopback while it runs. The ego pose served advances and is the pose trajectory.csv has at the served
simulated time; the traffic is there; the process ends by itself and frees the port; the drive's outputs are
byte-identical to the same drive without --view; a frozen view server never holds the loop up; Ctrl-C and
SIGTERM end the server too; a taken port is one line, exit 2; with --udm, the UDM objects are served where they
are."""

from __future__ import annotations

import csv
import json
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path

import psutil
import pytest
from click.testing import CliRunner

from twin.cli.main import cli

TWIN = str(Path(sys.executable).parent / "twin")
class _DefaultCtrlC:
    """Children started inside get Ctrl-C as a terminal gives it: a process started with SIGINT ignored keeps
    ignoring it (Python then installs no KeyboardInterrupt), and a test run earlier in the session may have left
    pytest so. A handled signal is reset to the default at exec; an ignored one is not."""

    def __enter__(self):
        self.previous = signal.signal(signal.SIGINT, signal.default_int_handler)

    def __exit__(self, *_):
        signal.signal(signal.SIGINT, self.previous)


DRIVE = ["--random", "--duration", "16", "--seed", "3", "--traffic", "6", "--pedestrians", "3", "--no-plot"]


class LiveDrive:
    """`twin drive ... --view --view-port 0 --no-browser` as a subprocess (own process group); ``url`` once the
    view listens (read from its stderr line), ``stderr`` all it wrote."""

    def __init__(self, build: Path, out: Path, *extra: str):
        with _DefaultCtrlC():
            self.process = subprocess.Popen([TWIN, "drive", "--map", str(build), *DRIVE, "-o", str(out), "--view",
                                             "--view-port", "0", "--no-browser", *extra],
                                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                            start_new_session=True)
        self.lines: list[str] = []
        self.url: str | None = None
        self._announced = threading.Event()
        threading.Thread(target=self._read, daemon=True).start()
        if not self._announced.wait(120) or self.url is None:
            self.kill()
            pytest.fail("twin drive --view did not announce its view: " + "".join(self.lines))

    def _read(self) -> None:
        for line in self.process.stderr:
            self.lines.append(line)
            found = re.search(r"live view on (http://127\.0\.0\.1:\d+/) while the drive runs$", line.strip())
            if found:
                self.url = found.group(1)
                self._announced.set()
        self._announced.set()

    @property
    def stderr(self) -> str:
        return "".join(self.lines)

    def get(self, path: str, timeout: float = 5.0) -> bytes:
        with urllib.request.urlopen(self.url + path, timeout=timeout) as response:
            return response.read()

    def view_process(self) -> psutil.Process:
        [child] = [c for c in psutil.Process(self.process.pid).children(recursive=True)
                   if "tavf_mapkit.view.live" in c.cmdline()]
        return child

    def kill(self) -> None:
        if self.process.poll() is None:
            os.killpg(self.process.pid, signal.SIGKILL)
            self.process.wait()


def _rows(path: Path) -> list[dict]:
    with path.open(newline="") as handle:
        return list(csv.DictReader(handle))


def _port_is_free(url: str) -> bool:
    """Nobody listens there any more: a connection is refused, and a server may bind it again (with
    SO_REUSEADDR, as the view's own: the closed connections of the polls linger in TIME_WAIT)."""
    from tavf_mapkit.view.server import bind

    port = int(url.rstrip("/").rsplit(":", 1)[1])
    with socket.socket() as probe:
        if probe.connect_ex(("127.0.0.1", port)) == 0:
            return False
    try:
        bind(port).close()
    except OSError:
        return False
    return True


@pytest.fixture(scope="module")
def watched_drive(sample_build_dir, tmp_path_factory):
    """The drive at 4x real time (4 s of wall clock), /api/live polled at 20 Hz until the process ends."""
    out = tmp_path_factory.mktemp("live") / "run"
    drive = LiveDrive(sample_build_dir, out, "--pace", "4")
    states = []
    try:
        while drive.process.poll() is None:
            try:
                states.append(json.loads(drive.get("api/live")))
            except (urllib.error.URLError, ConnectionError):
                pass  # the server stopped between the poll and the process' end
            time.sleep(0.05)
        drive.process.wait(60)
    finally:
        drive.kill()
    return drive, out, states


def test_the_served_ego_is_the_drive_at_the_served_time(watched_drive):
    drive, out, states = watched_drive
    assert drive.process.returncode == 0, drive.stderr
    rows = {row["t"]: row for row in _rows(out / "trajectory.csv")}
    served = {state["seq"]: state for state in states if state["ego"] is not None}
    times = [served[seq]["t"] for seq in sorted(served)]
    assert len(set(times)) >= 20  # 10 Hz of the wall clock over 4 s
    assert times == sorted(times)  # newer states only
    assert f"{times[-1]:.3f}" == max(rows, key=float)  # it ended on the drive's last step...
    assert states[-1]["finished"] is True  # ...and said so before the server stopped
    for state in served.values():
        ego, row = state["ego"], rows[f"{state['t']:.3f}"]
        assert ego["t"] == state["t"]
        # trajectory.csv rounds x, y to 0.1 mm, yaw to 1e-6 rad, lat/lon to 1e-9 degrees; the view serves them exact
        for key, digits in (("x", 4), ("y", 4), ("z", 4), ("yaw", 6), ("speed", 4), ("lat", 9), ("lon", 9)):
            assert abs(ego[key] - float(row[key])) <= 0.51 * 10.0 ** -digits, (key, ego[key], row[key])
        assert (ego["road"], str(ego["lane"])) == (row["road"], row["lane"])
    first, last = served[min(served)]["ego"], served[max(served)]["ego"]
    assert ((last["x"] - first["x"]) ** 2 + (last["y"] - first["y"]) ** 2) ** 0.5 > 20.0  # it moved


def test_the_traffic_is_served_with_the_ego(watched_drive):
    _, _, states = watched_drive
    frames = [state["traffic"] for state in states if state["traffic"]]
    assert frames and any(frame["ids"] for frame in frames)
    for frame in frames:
        n = len(frame["ids"])
        assert all(len(frame[key]) == n for key in ("person", "x", "y", "yaw", "length", "width", "lat", "lon"))
    assert any(any(frame["person"]) for frame in frames) and any(not all(frame["person"]) for frame in frames)


def test_the_drive_ends_by_itself_and_frees_the_port(watched_drive):
    drive, out, _ = watched_drive
    view = json.loads((out / "metrics.json").read_text())["view"]
    assert view["url"] == drive.url and view["states_sent"] >= 20 and view["states_skipped"] == 0
    assert _port_is_free(drive.url)
    assert "Traceback" not in drive.stderr


def test_the_page_is_the_view_page_following_the_drive(sample_build_dir, tmp_path):
    """While a drive runs: the page of mapkit view with the live option, the map and scene of the build."""
    drive = LiveDrive(sample_build_dir, tmp_path / "run", "--pace", "2")
    try:
        page = drive.get("").decode()
        assert "static/live.js" in page and '"live": {"rate_hz": 10.0}' in page
        lanes = json.loads(drive.get("api/map", timeout=60))["lane_count"]
        summary = json.loads((sample_build_dir / "report" / "summary.json").read_text())
        assert lanes == summary["stages"]["opendrive"]["lanes"]
        assert json.loads(drive.get("api/scene"))["mesh"]["tiles"]
    finally:
        drive.kill()


def test_outputs_are_byte_identical_without_view(watched_drive, sample_build_dir, tmp_path):
    """The view only reads: the same drive without --view (and unpaced) writes the same files."""
    _, out, _ = watched_drive
    plain = tmp_path / "plain"
    subprocess.run([TWIN, "drive", "--map", str(sample_build_dir), *DRIVE, "-o", str(plain)], check=True,
                   capture_output=True, timeout=300)
    for name in ("trajectory.csv", "gnss.csv", "imu.csv", "collisions.csv"):
        assert (plain / name).read_bytes() == (out / name).read_bytes(), name


def test_a_frozen_view_server_never_holds_the_loop_up(sample_build_dir, tmp_path):
    """SIGSTOP the view's process: the loop keeps its pace (snapshots find no room and are skipped, not
    waited for), and the end of the drive kills the frozen server after its close timeout."""
    drive = LiveDrive(sample_build_dir, tmp_path / "run", "--pace", "8", "--view-rate", "60")
    try:
        view = drive.view_process()
        view.suspend()
        drive.process.wait(120)
        assert drive.process.returncode == 0, drive.stderr
        metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
        assert metrics["view"]["states_skipped"] > 0
        assert metrics["wall_seconds"] < 6.0  # paced at 2 s: not stalled by the frozen child
        assert not view.is_running() or view.status() == psutil.STATUS_ZOMBIE
        assert _port_is_free(drive.url)
    finally:
        drive.kill()


@pytest.mark.parametrize("how", ["ctrl-c", "sigterm"])
def test_ctrl_c_and_sigterm_stop_the_server(sample_build_dir, tmp_path, how):
    # long enough that a loaded machine cannot finish it before the signal (16 s at real time did, in CI)
    drive = LiveDrive(sample_build_dir, tmp_path / "run", "--pace", "1", "--duration", "600")
    try:
        assert json.loads(drive.get("api/live"))["finished"] is False
        view = drive.view_process()
        if how == "ctrl-c":
            os.killpg(drive.process.pid, signal.SIGINT)  # a terminal's Ctrl-C: to the whole process group
        else:
            drive.process.terminate()  # the twin alone: its view server sees the pipe close
        assert drive.process.wait(30) == 130  # SIGTERM is handled like Ctrl-C: the same cleanup runs
        view.wait(15)
        assert _port_is_free(drive.url)
        assert "Traceback" not in drive.stderr
        # nothing half-written: no output folder, and no staging folder left beside it
        assert sorted(path.name for path in tmp_path.iterdir() if path.name.startswith((".run", "run"))) == []
    finally:
        drive.kill()


def test_a_taken_port_is_one_line_exit_2(sample_build_dir, tmp_path):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen(1)
        port = taken.getsockname()[1]
        started = time.perf_counter()
        result = CliRunner().invoke(cli, ["drive", "--map", str(sample_build_dir), "--random", "--view",
                                          "--view-port", str(port), "-o", str(tmp_path / "run")])
    assert result.exit_code == 2
    assert result.output.strip().splitlines() == [(f"Error: cannot listen on 127.0.0.1:{port}: Address already in "
                                                   f"use (give another --view-port; 0 picks a free one)")]
    assert time.perf_counter() - started < 5.0  # before the world is set up
    assert not (tmp_path / "run").exists()


def test_udm_objects_are_served_where_they_are(sample_build_dir, tmp_path):
    """With --udm: the objects of the UDM's latest answer, in WGS84 and at the same place in the local frame."""
    from tavf_mapkit.opendrive import load_opendrive
    from twin.udm.seed import seed_from_build
    from twin.udm.server import ServerThread, create_app
    from twin.udm.store import SqliteRtreeStore

    store = SqliteRtreeStore()
    seed_from_build(store, sample_build_dir)
    served = []
    with ServerThread(create_app(store, "token")) as server:
        drive = LiveDrive(sample_build_dir, tmp_path / "run", "--pace", "4", "--udm", server.url, "--udm-bbox", "400")
        try:
            while drive.process.poll() is None:
                try:
                    state = json.loads(drive.get("api/live"))
                except (urllib.error.URLError, ConnectionError):
                    break
                if state["udm"] and state["udm"]["objects"]:
                    served.append(state["udm"])
                time.sleep(0.1)
            assert drive.process.wait(60) == 0, drive.stderr
        finally:
            drive.kill()
    store.close()
    assert served, "no UDM object was served"
    georef = load_opendrive(next(sample_build_dir.glob("*.xodr"))).georeference
    known = {f["id"] for features in _recorded_answers(tmp_path / "run") for f in features}
    for answer in served:
        assert answer["status"] == "ok"
        for obj in answer["objects"]:
            assert obj["id"] in known  # an object the drive's recording has in one of its answers
            x, y = georef.wgs84_to_local(obj["lon"], obj["lat"])
            assert (obj["x"], obj["y"]) == pytest.approx((float(x), float(y)), abs=1e-3)


def _recorded_answers(run: Path) -> list[list[dict]]:
    from twin.recording.reader import read_recording

    return [record["features"] for record in read_recording(run / "session.mcap").udm_responses]
