"""mapkit validate vs the ASAM Quality Checker's OpenDRIVE bundle (asam-qc-opendrive), same files, same run.

    $ .venv/bin/python benchmarks/bench_validate.py [--repeat 3] [--no-peers]

Files: netconvert's OpenDRIVE of DLR's TAVF network (made here with the eclipse-sumo wheel), CARLA's Town07
(libOpenDRIVE's test file) and, when present, the Jungfernstieg build (build/jungfernstieg). Target (TAVF):
validate_file <= 2 s. asam-qc-opendrive pins numpy < 2, so it runs in its own venv (benchmarks/.peers/qc,
created on first use); its time is the whole process (it has no library entry point that skips the CLI), ours is
given both in-process and as a whole process. Findings are printed side by side: ours by rule and severity,
theirs by checker and level (1 error, 2 warning, 3 info) and which checkers it skipped.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
import venv
from collections import Counter
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
SHARED = REPO.parent / "shared" / "data"
PEERS = HERE / ".peers"
TARGET_S = 2.0

OURS = r"""
import json, sys, time
t0 = time.perf_counter()
from tavf_mapkit.validate import validate_file
t1, c1 = time.perf_counter(), time.process_time()
report = validate_file(sys.argv[1])
t2, c2 = time.perf_counter(), time.process_time()
s = report.summary
print(json.dumps({"import": t1 - t0, "validate": t2 - t1, "cpu": c2 - c1, "errors": s["errors"], "warnings": s["warnings"],
                  "info": s["info"], "by_rule": s["by_rule"]}))
"""

_QC_CHECKER_WORDS = """valid_xml_document root_tag_is_opendrive fileheader_is_present version_is_defined valid_schema
road_lane_level_true_one_side road_lane_access_no_mix_of_deny_or_allow road_lane_link_lanes_across_lane_sections
road_linkage_is_junction_needed road_lane_link_zero_width_at_start road_lane_link_zero_width_at_end
road_lane_link_new_lane_appear junctions_connection_connect_road_no_incoming_road
junctions_connection_one_connection_element junctions_connection_one_link_to_incoming
junctions_connection_start_along_linkage junctions_connection_end_opposite_linkage
road_geometry_parampoly3_length_match road_lane_border_overlap_with_inner_lanes
road_geometry_parampoly3_arclength_range road_geometry_parampoly3_normalized_range
performance_avoid_redundant_info lane_smoothness_contact_point_no_horizontal_gaps"""
QC_CHECKERS = _QC_CHECKER_WORDS.split()
_XML_CHECKS = {"valid_xml_document", "root_tag_is_opendrive", "fileheader_is_present", "version_is_defined",
               "valid_schema"}


def qc_config(xodr: Path, result: Path) -> str:
    checkers = "\n".join(
        f'    <Checker checkerId="check_asam_xodr_{"xml_" if name in _XML_CHECKS else ""}{name}" maxLevel="1" '
        'minLevel="3"/>' for name in QC_CHECKERS)
    return f"""<?xml version="1.0" encoding="UTF-8" standalone="no"?>
<Config>
  <Param name="InputFile" value="{xodr}"/>
  <CheckerBundle application="xodrBundle">
    <Param name="resultFile" value="{result}"/>
{checkers}
  </CheckerBundle>
</Config>
"""


def peer_qc() -> Path | None:
    folder = PEERS / "qc"
    program = folder / "bin" / "qc_opendrive"
    if not program.exists():
        print(f"creating {folder} with asam-qc-opendrive ...", file=sys.stderr)
        venv.create(folder, with_pip=True)
        done = subprocess.run([str(folder / "bin" / "python"), "-m", "pip", "install", "-q", "asam-qc-opendrive"],
                              capture_output=True, text=True, check=False)
        if done.returncode != 0:
            print(f"  could not install asam-qc-opendrive: {done.stderr.strip()[-200:]}", file=sys.stderr)
            return None
    return program


def run_ours(path: Path) -> dict:
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-c", OURS, str(path)], capture_output=True, text=True, timeout=900,
                          check=False)
    wall = time.perf_counter() - start
    if done.returncode != 0 or not done.stdout.strip():
        return {"error": (done.stderr.strip().splitlines() or ["failed"])[-1][:200]}
    return {**json.loads(done.stdout.strip().splitlines()[-1]), "process": wall}


def run_qc(program: Path, path: Path, folder: Path) -> dict:
    from lxml import etree

    result, config = folder / f"{path.stem}.xqar", folder / f"{path.stem}.qc.xml"
    config.write_text(qc_config(path.resolve(), result))
    start = time.perf_counter()
    done = subprocess.run([str(program), "-c", str(config)], capture_output=True, text=True, timeout=1800,
                          cwd=folder, check=False)
    wall = time.perf_counter() - start
    if done.returncode != 0 or not result.exists():
        return {"error": (done.stderr.strip().splitlines() or ["failed"])[-1][:200], "process": wall}
    root = etree.parse(str(result)).getroot()
    issues, levels, skipped = Counter(), Counter(), []
    for checker in root.iter("Checker"):
        name = checker.get("checkerId").replace("check_asam_xodr_", "")
        if checker.get("status") == "skipped":
            skipped.append(name)
        for issue in checker.iter("Issue"):
            issues[name] += 1
            levels[{"1": "error", "2": "warning", "3": "info"}.get(issue.get("level"), issue.get("level"))] += 1
    return {"process": wall, "issues": dict(issues), "levels": dict(levels), "skipped": skipped}


def tavf_xodr(folder: Path) -> Path:
    from tavf_mapkit.netconvert import find_netconvert

    out = folder / "tavf.xodr"
    subprocess.run([str(find_netconvert()), "-s", str(SHARED / "hamburg" / "tavf_dlr_sumo_net" / "network.net.xml.gz"),
                    "--opendrive-output", str(out)], check=True, capture_output=True)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--no-peers", action="store_true")
    args = parser.parse_args()
    program = None if args.no_peers else peer_qc()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        files = {"TAVF (netconvert)": tavf_xodr(folder), "Town07": SHARED / "xodr" / "libopendrive" / "test.xodr"}
        jungfernstieg = REPO / "build" / "jungfernstieg" / "jungfernstieg.xodr"
        if jungfernstieg.exists():
            files["Jungfernstieg build"] = jungfernstieg
        rows = []
        for label, path in files.items():
            ours = [run_ours(path) for _ in range(args.repeat)]
            good = [r for r in ours if "error" not in r]
            row = {"file": label, "size_mb": path.stat().st_size / 1e6,
                   "ours": {**good[0], "validate": statistics.median(r["validate"] for r in good),
                            "process": statistics.median(r["process"] for r in good),
                            "cpu": statistics.median(r["cpu"] for r in good)} if good else ours[0]}
            if program is not None:
                row["qc"] = run_qc(program, path, folder)
            rows.append(row)
    for row in rows:
        ours, qc = row["ours"], row.get("qc")
        print(f"\n== {row['file']} ({row['size_mb']:.1f} MB)")
        if "error" in ours:
            print(f"  mapkit validate FAILED: {ours['error']}")
        else:
            print(f"  mapkit validate   {ours['validate']:.2f} s in process ({ours['cpu']:.2f} s CPU), "
                  f"{ours['process']:.2f} s as a process; "
                  f"{ours['errors']} errors, {ours['warnings']} warnings, {ours['info']} info")
            for rule, count in ours["by_rule"].items():
                print(f"      {count:>5}  {rule}")
        if qc is None:
            continue
        if "error" in qc:
            print(f"  asam-qc-opendrive FAILED after {qc['process']:.2f} s: {qc['error']}")
            continue
        ratio = qc["process"] / ours["process"] if "process" in ours else float("nan")
        levels = ", ".join(f"{n} {level}" for level, n in sorted(qc["levels"].items())) or "no issues"
        print(f"  asam-qc-opendrive {qc['process']:.2f} s as a process ({ratio:.1f}x ours); {levels}; "
              f"{len(qc['skipped'])} of {len(QC_CHECKERS)} checkers skipped (failed preconditions)")
        for name, count in sorted(qc["issues"].items()):
            print(f"      {count:>5}  {name}")
    tavf = rows[0]["ours"]
    if "validate" in tavf:
        print(f"\nTAVF target: validate {tavf['validate']:.2f} s / {TARGET_S:.0f} s = {tavf['validate'] / TARGET_S:.2f} "
              f"(CPU {tavf['cpu']:.2f} s; load average now {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores)")


if __name__ == "__main__":
    main()
