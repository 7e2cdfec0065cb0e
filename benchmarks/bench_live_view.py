"""What ``twin drive --view`` costs the simulation: real-time factor of the same seeded drive without and with
the live view (and with a headless chromium watching the page, when Debian's chromium and playwright are here).

    $ .venv/bin/python benchmarks/bench_live_view.py [--build build/NAME] [--rounds 5] [--duration 120]

Without --build the sample district is built first (into a temporary folder). Each drive is ``twin drive
--random --seed 0 --traffic 20 --pedestrians 10`` as its own process; its real-time factor is the loop's
(metrics.json: simulated seconds over the loop's wall time, set-up excluded). The machine has two cores shared
with other jobs, so the modes run interleaved, round by round in a rotating order, and the figure is the median
over rounds of each round's ratio to the drive without the view (target: the view costs under 10 %). Every
drive must write the same trajectory.csv, byte for byte.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
BIN = Path(sys.executable).parent
SAMPLE = REPO / "sample_data" / "tavf_synthetic.osm"
TARGET_COST = 0.10


# chromium on a machine without a GPU: the tests' flags make SwiftShader draw everything (WebGL, the 2D
# canvases and the compositing, in its GPU process); "default" leaves chromium its own fallback (software
# compositing, SwiftShader for WebGL only), which a desktop chromium without a GPU uses
CHROMIUM_FLAGS = {"swiftshader": ["--enable-unsafe-swiftshader", "--use-angle=swiftshader"],
                  "default": ["--enable-unsafe-swiftshader"]}


class Browser:
    """One headless chromium (playwright) for every watched drive; None when it is not installed."""

    def __init__(self, flags: str):
        from playwright.sync_api import sync_playwright

        self._playwright = sync_playwright().start()
        self.browser = self._playwright.chromium.launch(
            executable_path=shutil.which("chromium") or shutil.which("chromium-browser"), args=CHROMIUM_FLAGS[flags])

    @classmethod
    def maybe(cls, flags: str):
        if not (shutil.which("chromium") or shutil.which("chromium-browser")):
            return None
        try:
            import playwright.sync_api  # noqa: F401
        except ImportError:
            return None
        return cls(flags)

    def cpu_seconds(self) -> float:
        """CPU time (user + system) of every chromium process so far."""
        import psutil

        total = 0.0
        for process in psutil.Process().children(recursive=True):
            try:
                if "chrom" in process.name():
                    times = process.cpu_times()
                    total += times.user + times.system
            except psutil.Error:
                pass
        return total

    def close(self) -> None:
        self.browser.close()
        self._playwright.stop()


def _watch_view_server(process) -> list[float]:
    """[CPU seconds] of the twin's live view process, sampled every 0.2 s until it ends (the last sample)."""
    import psutil

    used = [0.0]

    def watch() -> None:
        child = None
        while process.poll() is None:
            try:
                if child is None:
                    child = next((c for c in psutil.Process(process.pid).children()
                                  if "tavf_mapkit.view.live" in c.cmdline()), None)
                if child is not None:
                    times = child.cpu_times()
                    used[0] = times.user + times.system
            except psutil.Error:
                pass
            time.sleep(0.2)

    threading.Thread(target=watch, daemon=True).start()
    return used


def _live_time(url: str) -> tuple[float, float | None, bool]:
    """(wall clock, simulated time, finished) of the drive's newest state, read from its view server (which
    reads the twin's snapshots every 0.1 s)."""
    import urllib.request

    with urllib.request.urlopen(url + "api/live", timeout=5) as response:
        state = json.loads(response.read())
    return time.perf_counter(), state["t"], bool(state["finished"])


def drive(build: Path, out: Path, duration: float, mode: str, browser: Browser | None) -> dict:
    command = [str(BIN / "twin"), "drive", "--map", str(build), "--random", "--duration", str(duration), "--seed",
               "0", "--traffic", "20", "--pedestrians", "10", "--no-plot", "-o", str(out)]
    if mode != "plain":
        command += ["--view", "--view-port", "0", "--no-browser"]
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    lines: list[str] = []
    announced = threading.Event()
    url: list[str] = []

    def read() -> None:
        for line in process.stderr:
            lines.append(line)
            found = re.search(r"(http://127\.0\.0\.1:\d+/)", line)
            if found and not url:
                url.append(found.group(1))
                announced.set()
        announced.set()

    threading.Thread(target=read, daemon=True).start()
    page = None
    updates = None
    if mode == "browser":
        announced.wait(300)
        page = browser.browser.new_page(viewport={"width": 1400, "height": 850})
        page.goto(url[0])
    server_cpu = _watch_view_server(process) if mode != "plain" else None
    loaded_after = rtf_after_load = None
    if page is not None:
        started = time.perf_counter()
        page.wait_for_function("document.body.dataset.ready === 'true'", timeout=600_000)
        loaded_after = time.perf_counter() - started
        browser_cpu = browser.cpu_seconds()
        # the loop's real-time factor while the loaded page watches (the load, a one-off, overlaps the drive's
        # first seconds): simulated seconds over wall seconds from the load to the last state before the end
        first = last = _live_time(url[0])
        while process.poll() is None:
            time.sleep(0.5)
            try:
                sample = _live_time(url[0])
            except OSError:
                break  # the drive ended and its server with it
            if sample[2]:
                break
            last = sample
        if first[1] is not None and last[0] - first[0] > 2.0:
            rtf_after_load = (last[1] - first[1]) / (last[0] - first[0])
    if process.wait(1800) != 0:
        raise SystemExit(f"twin drive failed ({mode}): {''.join(lines)[-2000:]}")
    if page is not None:
        browser_cpu = browser.cpu_seconds() - browser_cpu
        watched_s = time.perf_counter() - started - loaded_after
        updates = page.evaluate("window.mapkit && window.mapkit.live ? window.mapkit.live.updates : 0")
        page.close()
    metrics = json.loads((out / "metrics.json").read_text())
    return {"mode": mode, "rtf": metrics["real_time_factor"], "wall_s": metrics["wall_seconds"],
            "trajectory_sha256": hashlib.sha256((out / "trajectory.csv").read_bytes()).hexdigest(),
            "view": metrics.get("view"), "page_updates": updates,
            "server_cpu_s": server_cpu[0] if server_cpu else None,
            # the page's load (map data, 3D tiles) and then chromium's CPU while it watched the rest of the drive
            "page_load_s": loaded_after, "browser_cpu_s_after_load": browser_cpu if page is not None else None,
            "rtf_after_load": rtf_after_load, "watched_s": watched_s if page is not None else None}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--build", type=Path, help="an existing build folder (default: build the sample)")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--duration", type=float, default=120.0, help="simulated seconds per drive")
    parser.add_argument("--no-browser", action="store_true", help="skip the mode with chromium watching")
    parser.add_argument("--chromium-flags", choices=sorted(CHROMIUM_FLAGS), default="swiftshader",
                        help="swiftshader: SwiftShader draws everything (as the tests run it); default: chromium's "
                             "own fallback without a GPU (software compositing)")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    browser = None if args.no_browser else Browser.maybe(args.chromium_flags)
    modes = ["plain", "view"] + (["browser"] if browser is not None else [])
    runs: list[dict] = []
    with tempfile.TemporaryDirectory(prefix="bench-live-") as tmp:
        tmp = Path(tmp)
        build = args.build
        if build is None:
            build = tmp / "sample"
            subprocess.run([str(BIN / "mapkit"), "build", str(SAMPLE), "-o", str(build), "-q"], check=True,
                           capture_output=True)
        try:
            for round_index in range(args.rounds):
                shift = round_index % len(modes)
                for mode in modes[shift:] + modes[:shift]:  # rotate: no mode always runs first or last
                    result = drive(build, tmp / f"{mode}-{round_index}", args.duration, mode, browser)
                    result["round"] = round_index
                    runs.append(result)
                    print(f"round {round_index} {mode:8s} {result['rtf']:7.2f}x real time", file=sys.stderr)
        finally:
            if browser is not None:
                browser.close()
    identical = len({run["trajectory_sha256"] for run in runs}) == 1
    summary = {"build": str(args.build or "sample"), "duration_s": args.duration, "rounds": args.rounds,
               "chromium_flags": CHROMIUM_FLAGS[args.chromium_flags] if browser is not None else None,
               "identical_trajectories": identical, "modes": {}}
    plain = {run["round"]: run["rtf"] for run in runs if run["mode"] == "plain"}
    for mode in modes:
        mine = [run for run in runs if run["mode"] == mode]
        ratios = [run["rtf"] / plain[run["round"]] for run in mine]
        summary["modes"][mode] = {"rtf_median": statistics.median(r["rtf"] for r in mine),
                                  "rtf": [r["rtf"] for r in mine], "ratio_median": round(statistics.median(ratios), 4),
                                  "ratios": [round(r, 4) for r in ratios],
                                  "cost": round(1 - statistics.median(ratios), 4),
                                  "page_updates": [r["page_updates"] for r in mine if r["page_updates"] is not None],
                                  "states_sent": [r["view"]["states_sent"] for r in mine if r["view"]],
                                  # the loop's own cost: time in the hand-overs over the loop's wall time
                                  "hand_over_share": [round(r["view"]["hand_over_seconds"] / r["wall_s"], 5)
                                                      for r in mine if r["view"]],
                                  "server_cpu_share": [round(r["server_cpu_s"] / r["wall_s"], 4)
                                                       for r in mine if r["server_cpu_s"] is not None],
                                  # chromium's CPU over the wall time it watched the loaded page, in cores
                                  "browser_cores": [round(r["browser_cpu_s_after_load"] / r["watched_s"], 3)
                                                    for r in mine if r["watched_s"]],
                                  "ratios_after_load": [round(r["rtf_after_load"] / plain[r["round"]], 4)
                                                        for r in mine if r["rtf_after_load"] is not None]}
    if args.json:
        print(json.dumps({**summary, "runs": runs}, indent=2))
    else:
        print(f"{'mode':10s} {'RTF median':>10s} {'ratio to plain':>15s} {'cost':>7s}  target")
        for mode, figures in summary["modes"].items():
            target = "" if mode == "plain" else f"< {TARGET_COST:.0%}"
            print(f"{mode:10s} {figures['rtf_median']:9.2f}x {figures['ratio_median']:15.3f} "
                  f"{figures['cost']:7.1%}  {target}")
            if figures["ratios_after_load"]:
                print(f"           after the page loaded: ratio to plain "
                      f"{statistics.median(figures['ratios_after_load']):.3f} (rounds {figures['ratios_after_load']}); "
                      f"chromium {figures['browser_cores']} cores")
            if figures["hand_over_share"]:
                print(f"           hand-overs: {statistics.median(figures['hand_over_share']):.3%} of the loop's "
                      f"wall time; view server: {statistics.median(figures['server_cpu_share']):.1%} of a core")
        print(f"trajectories byte-identical across all {len(runs)} drives: {identical}")
    if not identical:
        raise SystemExit("trajectories differ between drives")


if __name__ == "__main__":
    main()
