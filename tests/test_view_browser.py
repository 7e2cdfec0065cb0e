"""A real headless browser (Debian's chromium, driven by playwright) against `mapkit view` of a zoo build and
a recorded drive, and against the build's report/index.html opened from disk.

The page must load without console errors and without a request outside the local server (no CDN); the 2D
map has one lane feature per lane of the build; clicking a finding marker opens its popup with rule and
road; the 3D canvas is not blank; the time slider moves the ego on both views to the recorded positions.
`twin drive --view` on the same build: the page follows the running drive (the ego moves on both views, where
the served state says) at the bounded rate of a browser drawing in software, drawing one 3D frame per update
and none while nothing changes, and shows that the drive ended.
Skips where chromium or playwright is missing, fails under CI=true (.ci/run installs chromium).
"""

from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import _build, shared_path

pytestmark = pytest.mark.slow

BIN = Path(sys.executable).parent
CHROMIUM_ARGS = ["--enable-unsafe-swiftshader", "--use-angle=swiftshader"]  # WebGL without a GPU


def _chromium() -> str:
    found = shutil.which("chromium") or shutil.which("chromium-browser")
    problem = None
    if found is None:
        problem = "no chromium on this machine (apt-get install chromium)"
    else:
        try:
            import playwright.sync_api  # noqa: F401
        except ImportError:
            problem = "playwright is not installed (pip install -e '.[test]')"
    if problem:
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(f"{problem} -- in CI, .ci/run installs it first")
        pytest.skip(problem)
    return found


@pytest.fixture(scope="module")
def browser():
    executable = _chromium()
    from playwright.sync_api import sync_playwright

    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=executable, args=CHROMIUM_ARGS)
        yield browser
        browser.close()


@pytest.fixture(scope="module")
def perth(tmp_path_factory) -> Path:
    return _build(tmp_path_factory, "perth", shared_path("zoo", "osm", "AU_perth_peanut_roundabout_LHT.osm.gz"))


@pytest.fixture(scope="module")
def perth_run(perth, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("perth-run") / "run"
    subprocess.run([str(BIN / "twin"), "drive", "--map", str(perth), "--random", "--duration", "20", "--seed", "0",
                    "--traffic", "6", "--pedestrians", "3", "--no-plot", "-o", str(out)],
                   check=True, capture_output=True, timeout=300)
    return out


@pytest.fixture(scope="module")
def server(perth, perth_run):
    """`mapkit view BUILD RUN --port 0 --no-browser --json` as a subprocess; yields its URL, stops it after."""
    process = subprocess.Popen([str(BIN / "mapkit"), "view", str(perth), str(perth_run), "--port", "0",
                                "--no-browser", "--json"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True)
    line: list[str] = []
    reader = threading.Thread(target=lambda: line.append(process.stdout.readline()), daemon=True)
    reader.start()
    reader.join(timeout=120)
    try:
        if not line or not line[0]:
            process.kill()
            pytest.fail(f"mapkit view did not start: {process.communicate(timeout=10)[1]}")
        yield json.loads(line[0])["url"], process
    finally:
        if process.poll() is None:
            process.send_signal(signal.SIGTERM)
            try:
                process.wait(timeout=15)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()


class Watched:
    """A page with every console error, page error, failed request and request URL recorded."""

    def __init__(self, browser, viewport=(1400, 850)):
        self.page = browser.new_page(viewport={"width": viewport[0], "height": viewport[1]})
        self.errors: list[str] = []
        self.requests: list[str] = []
        self.page.on("console", lambda m: self.errors.append(f"console.{m.type}: {m.text}")
                     if m.type == "error" else None)
        self.page.on("pageerror", lambda e: self.errors.append(f"page error: {e}"))
        self.page.on("requestfailed", lambda r: self.errors.append(f"request failed: {r.url}"))
        self.page.on("request", lambda r: self.requests.append(r.url))


def _lanes_of(build: Path) -> int:
    return json.loads((build / "report" / "summary.json").read_text())["stages"]["opendrive"]["lanes"]


def _click_a_finding(page) -> str:
    """Click the finding marker drawn last (on top where two share a place); the popup's text."""
    markers = page.locator(".finding-marker")
    assert markers.count() > 0, "the build has no finding with a road to show"
    markers.last.click()
    popup = page.locator(".leaflet-popup-content")
    popup.wait_for(state="visible", timeout=5000)
    return popup.inner_text()


def test_live_page(browser, server, perth, perth_run):
    url, process = server
    watched = Watched(browser)
    page = watched.page
    page.goto(url)
    page.wait_for_function("document.body.dataset.ready === 'true'", timeout=120_000)

    # 2D: one lane feature per lane of the build
    assert page.evaluate("window.mapkit.map2d.layers.lanes.getLayers().length") == _lanes_of(perth)

    # a finding marker opens its popup naming rule and road
    findings = [f for f in json.loads((perth / "report" / "validate.json").read_text())["findings"] if f["road"]]
    text = _click_a_finding(page)
    assert any(f["rule"] in text and f"road {f['road']}" in text for f in findings), text

    # 3D: every mesh tile and collision body loaded, and the canvas shows them (many colours, not one)
    loaded = page.evaluate("window.mapkit.scene3d.loaded")
    tiles = json.loads((perth / "mesh" / "mesh.json").read_text())["tiles"]
    assert loaded == {"tiles": len(tiles), "bodies": loaded["bodies"], "failed": 0} and loaded["bodies"] > 0
    import io

    from PIL import Image

    image = np.asarray(Image.open(io.BytesIO(page.locator("#view3d canvas").screenshot())).convert("RGB"))
    colours = np.unique(image.reshape(-1, 3), axis=0)
    assert len(colours) > 50 and image.std() > 10, (len(colours), image.std())

    # the time slider moves the ego, on both views, to the recorded positions
    with (perth_run / "trajectory.csv").open(newline="") as handle:
        rows = list(csv.DictReader(handle))
    ego = "[window.mapkit.map2d.replay.ego.getLatLng(), window.mapkit.scene3d.ego.position.toArray()]"
    (start_2d, start_3d) = page.evaluate(ego)
    assert (start_2d["lat"], start_2d["lng"]) == pytest.approx((float(rows[0]["lat"]), float(rows[0]["lon"])),
                                                               abs=1e-8)
    page.locator("#replay-slider").focus()
    page.keyboard.press("End")
    (end_2d, end_3d) = page.evaluate(ego)
    assert (end_2d["lat"], end_2d["lng"]) == pytest.approx((float(rows[-1]["lat"]), float(rows[-1]["lon"])),
                                                           abs=1e-8)
    # glTF frame of the mesh origin (0, 0, 0 for our builds): X = x, Z = -y
    assert (end_3d[0], end_3d[2]) == pytest.approx((float(rows[-1]["x"]), -float(rows[-1]["y"])), abs=1e-3)
    assert np.hypot(end_3d[0] - start_3d[0], end_3d[2] - start_3d[2]) > 10.0
    assert page.locator("#replay-time").inner_text().startswith(f"t = {float(rows[-1]['t']):.2f} s")

    assert watched.errors == []
    # nothing but the local server: no CDN, no tiles (the online base map is off by default)
    assert all(u.startswith((url, "data:")) for u in watched.requests), \
        [u for u in watched.requests if not u.startswith(url)]
    page.close()
    assert process.poll() is None  # still serving


def test_report_opens_from_disk(browser, perth):
    report = perth / "report" / "index.html"
    watched = Watched(browser)
    page = watched.page
    page.goto(report.as_uri())
    page.wait_for_function("window.mapkit && window.mapkit.map2d", timeout=30_000)
    assert page.evaluate("window.mapkit.map2d.layers.lanes.getLayers().length") == _lanes_of(perth)
    text = _click_a_finding(page)
    assert "road " in text and "." in text.split()[0]  # "topology.dead-end ... road 218, s=..."
    assert watched.errors == []
    assert all(u == report.as_uri() or u.startswith("data:") for u in watched.requests), watched.requests
    page.close()


def test_server_stops_on_sigterm(server):
    """uvicorn shuts down (open connections closed) and ends by SIGTERM as asked, with no traceback."""
    _, process = server
    process.send_signal(signal.SIGTERM)
    assert process.wait(timeout=15) == -signal.SIGTERM
    assert "Traceback" not in process.stderr.read()


def test_live_drive_moves_the_ego(browser, perth, tmp_path):
    """`twin drive --view` on the Perth build: the page follows the running drive -- the ego moves on both
    views, where the served state says it is -- and says when the drive has ended, with no console error."""
    import re
    import time

    out = tmp_path / "live"
    process = subprocess.Popen([str(BIN / "twin"), "drive", "--map", str(perth), "--random", "--duration", "60",
                                "--seed", "0", "--traffic", "6", "--pedestrians", "3", "--no-plot", "--pace", "2",
                                "--view", "--view-port", "0", "--no-browser", "-o", str(out)],
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, start_new_session=True)
    found: list[str] = []

    def read() -> None:
        for line in process.stderr:
            match = re.search(r"live view on (http://127\.0\.0\.1:\d+/)", line)
            if match:
                found.append(match.group(1))

    threading.Thread(target=read, daemon=True).start()
    try:
        deadline = time.monotonic() + 120
        while not found and process.poll() is None and time.monotonic() < deadline:
            time.sleep(0.1)
        assert found, "twin drive --view did not announce its view"
        url = found[0]
        watched = Watched(browser)
        page = watched.page
        page.goto(url)
        page.wait_for_function("document.body.dataset.ready === 'true' && window.mapkit.live.updates > 0",
                               timeout=120_000)
        where = """() => { const live = window.mapkit.live, ego = live.latest.ego;
                    return {t: ego.t, x: ego.x, y: ego.y, lat: ego.lat, lon: ego.lon, updates: live.updates,
                            map: window.mapkit.map2d.replay.ego.getLatLng(), frames: window.mapkit.scene3d.frames,
                            scene: window.mapkit.scene3d.ego.position.toArray()}; }"""
        # a headless chromium draws in software: the page asks for 2 updates a second, not the drive's 10
        assert page.evaluate("[window.mapkit.software, window.mapkit.live.rate_hz]") == [True, 2]
        first = page.evaluate(where)
        page.wait_for_function(f"window.mapkit.live.latest.ego.t > {first['t'] + 8}", timeout=60_000)
        later = page.evaluate(where)
        assert later["updates"] > first["updates"]
        # the 3D view draws on demand: one frame per update (the camera stands still), no animation loop
        assert later["updates"] - first["updates"] - 1 <= later["frames"] - first["frames"] \
            <= later["updates"] - first["updates"] + 1
        assert np.hypot(later["scene"][0] - first["scene"][0], later["scene"][2] - first["scene"][2]) > 5.0
        assert (later["map"]["lat"], later["map"]["lng"]) != (first["map"]["lat"], first["map"]["lng"])
        # where the state served last says (one evaluate runs between two polls: the views show that state)
        for state in (first, later):
            assert (state["map"]["lat"], state["map"]["lng"]) == pytest.approx((state["lat"], state["lon"]), abs=1e-9)
            assert (state["scene"][0], state["scene"][2]) == pytest.approx((state["x"], -state["y"]), abs=1e-3)
        assert process.wait(120) == 0
        page.wait_for_function("window.mapkit.live.stopped", timeout=10_000)
        assert page.evaluate("window.mapkit.live.finished") is True  # it saw the end before the server stopped
        assert page.locator("#live-badge").inner_text() == "ENDED"
        frames = page.evaluate("window.mapkit.scene3d.frames")
        page.wait_for_timeout(1000)
        assert page.evaluate("window.mapkit.scene3d.frames") == frames  # nothing changes, nothing is drawn
        assert watched.errors == []
        assert all(u.startswith((url, "data:")) for u in watched.requests)
        page.close()
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
