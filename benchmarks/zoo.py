"""The map zoo as a standing test: build, validate and drive every real map we have, one table row per map.

    $ .venv/bin/python benchmarks/zoo.py                                  # every map, 2 seeds x 600 s
    $ .venv/bin/python benchmarks/zoo.py --only oakland,krautsand --duration 120
    $ .venv/bin/python benchmarks/zoo.py --markdown docs/zoo.md --json benchmarks/results/zoo.json

For every map of ../shared/data/zoo (OSM extracts and OpenDRIVE files) plus the other real inputs of
../shared/data (Jungfernstieg, Berlin's Grosser Stern, Krautsand, DLR's TAVF network) it runs, each as its own
process under a wall-time and memory limit:

1. ``mapkit build INPUT`` (time, peak RSS of the whole process tree, road count of the result),
2. ``mapkit validate`` of the build's OpenDRIVE (errors, warnings by rule),
3. ``twin drive --random`` for each seed (resets, collisions, off-road seconds, turnarounds, restarts,
   real-time factor), and the first seed once more to check that its trajectory is byte-identical.

A map that is refused shows the command's own one-line reason; a command that prints a Python traceback, is
killed by a limit or exits without a reason is a failure of ours and marked so (``FAIL``). The exit code is 1
when any map failed one of the issue's acceptance rules (see ``row_problems``), else 0.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("TAVF_SHARED_DATA", REPO.parent / "shared" / "data"))
BIN = Path(sys.executable).parent
PAGE = os.sysconf("SC_PAGE_SIZE")

# The real inputs outside the zoo folder that every change must keep working on.
EXTRA_INPUTS = {
    "hamburg_jungfernstieg": SHARED / "hamburg" / "jungfernstieg_osm" / "jungfernstieg_2023-03-10.osm",
    "hamburg_tavf_dlr_net": SHARED / "hamburg" / "tavf_dlr_sumo_net" / "network.net.xml.gz",
    "berlin_siegessaeule": SHARED / "osm_small" / "berlin-siegessaeule.osm.gz",
    "krautsand": SHARED / "osm_small" / "krautsand.osm.gz",
}
PEAK_RSS_LIMIT_MIB = 2048  # the acceptance figure for a build


def zoo_inputs() -> dict[str, Path]:
    """Every map the zoo runs, by short name (file name without suffixes), in a stable order."""
    maps: dict[str, Path] = {}
    zoo = SHARED / "zoo"
    for path in sorted((zoo / "osm").glob("*")) + sorted((zoo / "xodr").glob("*.xodr")):
        maps[path.name.split(".")[0]] = path
    maps.update(EXTRA_INPUTS)
    return maps


@dataclasses.dataclass
class Limited:
    """What one command did under its limits."""

    code: int | None
    wall: float
    peak_rss_mib: float
    stdout: str
    stderr: str
    killed: str = ""  # "time" or "memory" when a limit stopped it

    @property
    def reason(self) -> str:
        """The command's one-line reason for a non-zero exit (its last non-empty stderr line)."""
        if self.killed:
            return f"killed: {self.killed} limit"
        lines = [line.strip() for line in self.stderr.splitlines() if line.strip()]
        return lines[-1] if lines else f"exit {self.code} without a message"

    @property
    def traceback(self) -> bool:
        return "Traceback (most recent call last)" in self.stderr + self.stdout


def group_rss_mib(pgid: int) -> float:
    """Resident memory of every process in process group ``pgid`` (MiB), read from /proc."""
    total = 0
    for entry in os.scandir("/proc"):
        if not entry.name.isdigit():
            continue
        try:
            with open(f"/proc/{entry.name}/stat") as handle:
                fields = handle.read().rsplit(")", 1)[1].split()
            if int(fields[2]) != pgid:  # field 5 of stat (pgrp), third after the command name
                continue
            with open(f"/proc/{entry.name}/statm") as handle:
                total += int(handle.read().split()[1]) * PAGE
        except (OSError, ValueError, IndexError):
            continue
    return total / 2**20


def run_limited(command: list[str], timeout: float, memory_mib: float, cwd: Path | None = None) -> Limited:
    """Run ``command`` in its own process group; kill the group past ``timeout`` s or ``memory_mib`` MiB."""
    start = time.perf_counter()
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        process = subprocess.Popen(command, stdout=out, stderr=err, stdin=subprocess.DEVNULL, cwd=cwd,
                                   start_new_session=True)
        peak, killed, status, usage = 0.0, "", None, None
        while status is None:
            pid, raw, usage = os.wait4(process.pid, os.WNOHANG)
            if pid:
                status = raw
                break
            peak = max(peak, group_rss_mib(process.pid))
            if not killed and peak > memory_mib:
                killed = "memory"
            elif not killed and time.perf_counter() - start > timeout:
                killed = "time"
            if killed:
                os.killpg(process.pid, signal.SIGKILL)
                _, status, usage = os.wait4(process.pid, 0)
                break
            time.sleep(0.2)
        process.returncode = os.waitstatus_to_exitcode(status)
        try:  # helpers the command left behind in its group
            os.killpg(process.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        wall = time.perf_counter() - start
        # ru_maxrss covers the command and every child it waited for; the polled sum covers live siblings
        peak = max(peak, usage.ru_maxrss / 1024 if usage else 0.0)
        out.seek(0)
        err.seek(0)
        return Limited(process.returncode, wall, peak, out.read().decode(errors="replace"),
                       err.read().decode(errors="replace"), killed)


@dataclasses.dataclass
class Drive:
    seed: int
    status: str  # "ok", "refused" (one-line reason) or "FAIL"
    reason: str = ""
    resets: int = 0
    collisions: int = 0
    off_road_s: float = 0.0
    turnarounds: int = 0
    restarts: int = 0
    distance_km: float = 0.0
    real_time_factor: float = 0.0
    wall: float = 0.0
    trajectory_sha256: str = ""


@dataclasses.dataclass
class Row:
    name: str
    input: str
    kind: str
    driving_side: str = ""
    build_status: str = ""  # "ok", "refused" or "FAIL"
    build_reason: str = ""
    build_s: float = 0.0
    build_peak_mib: float = 0.0
    roads: int = 0
    validation_errors: int | None = None
    validation_warnings: int | None = None
    warnings_by_rule: dict = dataclasses.field(default_factory=dict)
    errors_by_rule: dict = dataclasses.field(default_factory=dict)
    drives: list[Drive] = dataclasses.field(default_factory=list)
    deterministic: bool | None = None


def input_kind(path: Path) -> str:
    name = path.name.lower()
    if name.endswith(".xodr"):
        return "xodr"
    if ".net.xml" in name:
        return "sumo"
    return "osm"


def build_xodr(folder: Path) -> Path | None:
    found = sorted(folder.glob("*.xodr"))
    return found[0] if found else None


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest() if path.exists() else ""


def status_of(result: Limited) -> str:
    if result.code == 0:
        return "ok"
    # one line from our own error handling is a refusal; anything else is our failure
    return "FAIL" if (result.killed or result.traceback or result.code not in (1, 2)) else "refused"


def run_drive(build: Path, seed: int, args, scratch: Path, tag: str) -> Drive:
    out = scratch / f"run-{seed}{tag}"
    shutil.rmtree(out, ignore_errors=True)
    command = [str(BIN / "twin"), "drive", "--map", str(build), "--random", "--duration", str(args.duration),
               "--seed", str(seed), "-o", str(out)]
    result = run_limited(command, args.drive_timeout, args.memory_mib)
    drive = Drive(seed=seed, status=status_of(result), wall=round(result.wall, 2))
    if result.code != 0:
        drive.reason = result.reason
        return drive
    metrics = json.loads((out / "metrics.json").read_text())
    drive.resets = int(metrics.get("resets", 0))
    drive.collisions = int(metrics.get("collisions", 0))
    drive.off_road_s = float(metrics.get("off_road_seconds", 0.0))
    drive.turnarounds = int(metrics.get("turnarounds", 0))
    drive.restarts = int(metrics.get("restarts", 0))
    drive.distance_km = round(float(metrics.get("distance_m", 0.0)) / 1000, 2)
    drive.real_time_factor = float(metrics.get("real_time_factor") or 0.0)
    drive.trajectory_sha256 = sha256(out / "trajectory.csv")
    return drive


def run_map(name: str, source: Path, args, scratch: Path) -> Row:
    row = Row(name=name, input=str(source), kind=input_kind(source))
    folder = scratch / name / "build"
    if not args.incremental:
        shutil.rmtree(scratch / name, ignore_errors=True)
    command = [str(BIN / "mapkit"), "build", str(source), "-o", str(folder), "-q", "--json"]
    built = run_limited(command, args.build_timeout, args.memory_mib)
    row.build_status, row.build_s, row.build_peak_mib = status_of(built), round(built.wall, 2), round(
        built.peak_rss_mib, 1)
    if built.code != 0:
        row.build_reason = built.reason
        return row
    xodr = build_xodr(folder)
    manifest = json.loads((folder / "manifest.json").read_text()) if (folder / "manifest.json").exists() else {}
    side = manifest.get("driving_side") or ""
    row.driving_side = str(side.get("side", "") if isinstance(side, dict) else side)
    info = run_limited([str(BIN / "mapkit"), "info", str(xodr), "--json"], 600, args.memory_mib)
    if info.code == 0:
        row.roads = int(json.loads(info.stdout).get("counts", {}).get("roads", 0))
    checked = run_limited([str(BIN / "mapkit"), "validate", str(xodr), "--json", "--no-info"],
                          args.build_timeout, args.memory_mib)
    if checked.code in (0, 1) and checked.stdout.strip():
        report = json.loads(checked.stdout)
        for finding in report.get("findings", []):
            target = {"error": row.errors_by_rule, "warning": row.warnings_by_rule}.get(finding.get("severity"))
            if target is not None:
                target[finding["rule"]] = target.get(finding["rule"], 0) + 1
        row.validation_errors = sum(row.errors_by_rule.values())
        row.validation_warnings = sum(row.warnings_by_rule.values())
    else:
        row.build_reason = f"validate: {checked.reason}"
    for seed in args.seeds:
        row.drives.append(run_drive(folder, seed, args, scratch / name, ""))
    first = row.drives[0] if row.drives else None
    if first is not None and first.status == "ok" and args.repeat_check:
        again = run_drive(folder, first.seed, args, scratch / name, "-again")
        row.deterministic = again.status == "ok" and again.trajectory_sha256 == first.trajectory_sha256
    return row


def row_problems(row: Row) -> list[str]:
    """What keeps a map from meeting the acceptance rules: build ok within 2 GB, drives clean and repeatable."""
    problems = []
    if row.build_status != "ok":
        # an OpenDRIVE file may be refused for its own defect; everything else must build
        if not (row.kind == "xodr" and row.build_status == "refused"):
            problems.append(f"build {row.build_status}: {row.build_reason}")
        return problems
    if row.build_peak_mib > PEAK_RSS_LIMIT_MIB:
        problems.append(f"build peak {row.build_peak_mib:.0f} MiB > {PEAK_RSS_LIMIT_MIB}")
    for drive in row.drives:
        if drive.status != "ok":
            if drive.status == "FAIL" or row.kind != "xodr":
                problems.append(f"drive seed {drive.seed} {drive.status}: {drive.reason}")
        elif drive.resets or drive.collisions or drive.off_road_s:
            problems.append(f"drive seed {drive.seed}: {drive.resets} resets, {drive.collisions} collisions, "
                            f"{drive.off_road_s:g} s off road")
    if row.deterministic is False:
        problems.append("same seed, different trajectory")
    return problems


def summarise_drives(row: Row) -> dict:
    ok = [d for d in row.drives if d.status == "ok"]
    if not ok:
        reasons = [d.reason for d in row.drives if d.reason]
        return {"drive": reasons[0] if reasons else "-"}
    return {
        "resets": sum(d.resets for d in ok), "collisions": sum(d.collisions for d in ok),
        "off_road_s": round(sum(d.off_road_s for d in ok), 2),
        "turn/restart": f"{sum(d.turnarounds for d in ok)}/{sum(d.restarts for d in ok)}",
        "km": round(sum(d.distance_km for d in ok), 1),
        "rtf": round(min(d.real_time_factor for d in ok), 1),
        "drive": "ok" if len(ok) == len(row.drives) else next(d.reason for d in row.drives if d.status != "ok"),
    }


COLUMNS = ["map", "side", "build s", "peak MiB", "roads", "errors", "warnings", "resets", "collisions",
           "off-road s", "turn/restart", "km", "min RTF", "same seed", "result"]


def table_cells(row: Row) -> list[str]:
    drives = summarise_drives(row) if row.build_status == "ok" else {}
    problems = row_problems(row)
    if row.build_status != "ok":
        result = f"{row.build_status}: {row.build_reason}"
    else:
        result = "; ".join(problems) if problems else "ok"
    same = {True: "yes", False: "NO", None: "-"}[row.deterministic]
    return [row.name, row.driving_side or "-", f"{row.build_s:.1f}", f"{row.build_peak_mib:.0f}",
            str(row.roads or "-"), "-" if row.validation_errors is None else str(row.validation_errors),
            "-" if row.validation_warnings is None else str(row.validation_warnings),
            str(drives.get("resets", "-")), str(drives.get("collisions", "-")), str(drives.get("off_road_s", "-")),
            str(drives.get("turn/restart", "-")), str(drives.get("km", "-")), str(drives.get("rtf", "-")), same,
            result.replace("|", "/")]


def markdown(rows: list[Row], args) -> str:
    lines = [f"| {' | '.join(COLUMNS)} |", f"|{'---|' * len(COLUMNS)}"]
    lines += [f"| {' | '.join(table_cells(row))} |" for row in rows]
    warnings: dict[str, int] = {}
    for row in rows:
        for rule, count in row.warnings_by_rule.items():
            warnings[rule] = warnings.get(rule, 0) + count
    lines += ["", f"Drives: seeds {','.join(map(str, args.seeds))}, {args.duration:g} s each, summed over seeds; "
              "min RTF is the lower real-time factor of the seeds.", "",
              "Validation warnings over all builds, by rule: "
              + (", ".join(f"`{rule}` {count}" for rule, count in sorted(warnings.items())) or "none")]
    return "\n".join(lines) + "\n"


def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    parser.add_argument("--only", help="comma-separated substrings of map names to run (default: all)")
    parser.add_argument("--seeds", default="0,1", help="drive seeds (default 0,1)")
    parser.add_argument("--duration", type=float, default=600.0, help="simulated seconds per drive")
    parser.add_argument("--build-timeout", type=float, default=900.0, help="wall-time limit of a build (s)")
    parser.add_argument("--drive-timeout", type=float, default=600.0, help="wall-time limit of a drive (s)")
    parser.add_argument("--memory-mib", type=float, default=6144.0,
                        help="memory limit of any one command's process tree (MiB); the acceptance figure for a "
                             f"build is {PEAK_RSS_LIMIT_MIB} MiB")
    parser.add_argument("--no-repeat-check", dest="repeat_check", action="store_false",
                        help="skip the second drive of the first seed (byte-identical trajectory check)")
    parser.add_argument("--scratch", type=Path, help="where builds and runs go (default: a temporary folder)")
    parser.add_argument("--keep", action="store_true", help="keep the scratch folder")
    parser.add_argument("--incremental", action="store_true",
                        help="keep earlier builds in --scratch, so mapkit reuses their unchanged stages (build s "
                             "is then the rebuild time)")
    parser.add_argument("--json", type=Path, help="also write every row as JSON here")
    parser.add_argument("--markdown", type=Path, help="also write the table as Markdown here (e.g. docs/zoo.md)")
    args = parser.parse_args(argv)
    args.seeds = [int(s) for s in args.seeds.split(",") if s.strip()]
    return args


def main(argv=None) -> int:
    args = parse_args(argv)
    maps = zoo_inputs()
    missing = [str(path) for path in maps.values() if not path.exists()]
    if missing or not (SHARED / "zoo").is_dir():
        print(f"zoo: shared data missing: {', '.join(missing) or SHARED / 'zoo'}", file=sys.stderr)
        return 2
    if args.only:
        wanted = [w.strip().lower() for w in args.only.split(",") if w.strip()]
        maps = {name: path for name, path in maps.items() if any(w in name.lower() for w in wanted)}
    scratch = args.scratch or Path(tempfile.mkdtemp(prefix="mapkit-zoo-"))
    scratch.mkdir(parents=True, exist_ok=True)
    rows = []
    print(" | ".join(COLUMNS), flush=True)
    try:
        for name, source in maps.items():
            row = run_map(name, source, args, scratch)
            rows.append(row)
            print(" | ".join(table_cells(row)), flush=True)
    finally:
        if not args.keep and args.scratch is None:
            shutil.rmtree(scratch, ignore_errors=True)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps([dataclasses.asdict(row) for row in rows], indent=1) + "\n")
    if args.markdown:
        text = markdown(rows, args)
        heading = ("# The map zoo\n\nLatest table of `benchmarks/zoo.py` (see its docstring for what each column "
                   "measures).\n\n")
        args.markdown.write_text(heading + f"Command: `{' '.join(['python', 'benchmarks/zoo.py', *(argv or sys.argv[1:])])}`"
                                 + "\n\n" + text)
    failed = [row.name for row in rows if row_problems(row)]
    print(f"{len(rows) - len(failed)} passed, {len(failed)} failed" + (f": {', '.join(failed)}" if failed else ""))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
