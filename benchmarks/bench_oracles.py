"""Our OpenDRIVE next to three independent oracles, per input: how far every reader's lanes are from ours.

    $ .venv/bin/python benchmarks/bench_oracles.py                       # every input below
    $ .venv/bin/python benchmarks/bench_oracles.py --only tavf-build,tavf-raw --keep /tmp/oracle-builds
    $ .venv/bin/python benchmarks/bench_oracles.py --json benchmarks/results/oracles.json

Inputs: ``mapkit build`` (default options, stages up to opendrive: the stages after it do not change
NAME.xodr) of DLR's TAVF SUMO network, of the Jungfernstieg OSM extract and of two zoo maps (Krems,
Melbourne), and the raw OpenDRIVE netconvert writes for the TAVF network (``netconvert -s ...
--opendrive-output``, unrepaired).

Per input it prints
- our validator: errors and warnings (by rule below the table);
- libOpenDRIVE (C++, ../shared/tools/libopendrive): every lane border at 0.5 m joined with ours at the same
  (road, section, lane, s): how many samples lie more than 1 mm apart, p99 and max distance, the worst place;
- CARLA 0.9.16's client-side map: its waypoints every 2 m against our lane centre at the same (road, section,
  lane, s): median, p99, max distance (CARLA's locations are single-precision floats and it evaluates
  paramPoly3 as a polyline: a few centimetres near tight curves are CARLA's); "f32" is the median distance of
  our centres from themselves rounded to single precision, the floor no float reader can go below (it grows
  with the map's extent: ~0.15 mm on a map 10 km across);
- ASAM's quality checker (asam-qc-opendrive): issues by checker, and how many of its checkers it skipped
  (a failed precondition such as the schema check, or rules of a later OpenDRIVE version than the file's);
  netconvert writes OpenDRIVE 1.4, to which most of its rules (from 1.7 on) do not apply, so it also checks a
  copy whose header says 1.8 (the newest it knows): the file's content under today's rules and schema.

The peers live in benchmarks/peers and are made on first use (benchmarks/.peers; libOpenDRIVE needs g++ and
libpugixml-dev). Targets of issue 14: C++ within 1 mm on every sample, CARLA median < 0.1 mm and p99 < 1 cm,
ASAM 0 issues, validator 0 errors.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from peers import PeerUnavailable, asam_qc, carla_map, libopendrive
from peers.borders import border_agreement
from peers.centres import centre_agreement

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("TAVF_SHARED_DATA", REPO.parent / "shared" / "data"))
BIN = Path(sys.executable).parent
TAVF_NET = SHARED / "hamburg" / "tavf_dlr_sumo_net" / "network.net.xml.gz"
INPUTS = {  # name -> (what, source); source None: netconvert's raw OpenDRIVE of the TAVF network
    "tavf-build": ("DLR TAVF net, build", TAVF_NET),
    "jungfernstieg": (
        "Jungfernstieg OSM, build",
        SHARED / "hamburg" / "jungfernstieg_osm" / "jungfernstieg_2023-03-10.osm",
    ),
    "krems": ("zoo Krems OSM, build", SHARED / "zoo" / "osm" / "AT_krems.osm.gz"),
    "melbourne": ("zoo Melbourne OSM, build", SHARED / "zoo" / "osm" / "AU_melbourne_arterials_LHT.osm.pbf"),
    # the largest extents: CARLA's single-precision floats show most there
    "bayreuth": ("zoo Bayreuth OSM, build", SHARED / "zoo" / "osm" / "DE_bayreuth_north.osm.gz"),
    # a whole small country; road 18894 turns back on itself through a hairpin of 0.03 mm radius (a near-cusp)
    "andorra": ("zoo Andorra OSM, build", SHARED / "zoo" / "osm" / "AD_andorra.osm.pbf"),
    "tavf-raw": ("DLR TAVF net, raw netconvert", None),
}
PEER_OF = {"asam_qc": "qc", "asam_qc_1.8": "qc"}
PIPELINE = '[pipeline]\nstages = ["extract", "netconvert", "opendrive"]\n'


def make_xodr(name: str, source: Path | None, folder: Path) -> tuple[Path, float]:
    """The input's OpenDRIVE, made in ``folder`` (an existing build there is reused incrementally), and the
    seconds that took."""
    start = time.perf_counter()
    if source is None:
        out = folder / f"{name}.xodr"
        if not out.exists():
            from tavf_mapkit.netconvert import find_netconvert

            subprocess.run(
                [str(find_netconvert()), "-s", str(TAVF_NET), "--opendrive-output", str(out)],
                check=True,
                capture_output=True,
                timeout=600,
            )
        return out, time.perf_counter() - start
    build = folder / name
    pipeline = folder / "oracles.toml"
    pipeline.write_text(PIPELINE)
    done = subprocess.run(
        [str(BIN / "mapkit"), "build", str(source), "-o", str(build), "--pipeline", str(pipeline), "-q"],
        capture_output=True,
        text=True,
        timeout=1800,
    )
    if done.returncode != 0:
        raise RuntimeError(f"mapkit build {source.name} failed: {done.stderr.strip().splitlines()[-1:]}")
    return build / f"{name}.xodr", time.perf_counter() - start


def measure(xodr: Path, folder: Path, peers: dict, qc18: bool) -> dict:
    from tavf_mapkit.opendrive import load_opendrive
    from tavf_mapkit.validate import validate_file

    odr = load_opendrive(xodr)
    report = validate_file(str(xodr))
    errors, warnings = {}, {}
    for finding in report.findings:
        counts = (
            errors if finding.severity == "error" else warnings if finding.severity == "warning" else None
        )
        if counts is not None:
            counts[finding.rule] = counts.get(finding.rule, 0) + 1
    row = {
        "roads": len(odr.roads),
        "validate": {
            "errors": sum(errors.values()),
            "warnings": sum(warnings.values()),
            "errors_by_rule": errors,
            "warnings_by_rule": warnings,
        },
    }
    for name, run in (
        (
            "libopendrive",
            lambda: border_agreement(
                odr, libopendrive.lane_borders(xodr, 0.5, peers["libopendrive"]), 0.5
            ).summary(),
        ),
        ("carla", lambda: centre_agreement(odr, carla_map.waypoints(xodr, 2.0, peers["carla"])).summary()),
        ("asam_qc", lambda: asam_qc.check(xodr, folder, peers["qc"])),
        ("asam_qc_1.8", lambda: asam_qc.check(xodr, folder, peers["qc"], minor=8)),
    ):
        if name == "asam_qc_1.8" and not qc18:
            continue
        peer = peers[PEER_OF.get(name, name)]
        if isinstance(peer, str):
            row[name] = {"error": peer}
            continue
        start = time.perf_counter()
        try:
            row[name] = {**run(), "seconds": round(time.perf_counter() - start, 2)}
        except (RuntimeError, subprocess.TimeoutExpired) as error:
            row[name] = {"error": str(error)[:200]}
    return row


def get_peers(install: bool) -> dict:
    """Each peer's program, or the reason it is missing (a string)."""
    peers = {}
    for name, getter in (
        ("libopendrive", libopendrive.binary),
        ("carla", carla_map.python),
        ("qc", asam_qc.program),
    ):
        try:
            peers[name] = getter(install=install)
        except PeerUnavailable as error:
            peers[name] = str(error)
    return peers


def mm(value) -> str:
    return "-" if value is None else f"{value * 1000:.3f}" if value < 1e-3 else f"{value * 1000:.1f}"


def print_table(rows: dict) -> None:
    print(
        f"\n{'input':<30} {'roads':>5} {'errors':>6} {'warn':>5} | {'C++ samples':>11} {'>1mm':>6} "
        f"{'p99 mm':>7} {'max mm':>7} | {'CARLA wps':>9} {'med mm':>7} {'f32 mm':>7} {'p99 mm':>7} {'max mm':>7} | "
        "ASAM issues (checkers skipped) as the file / as 1.8"
    )
    for row in rows.values():
        cpp, carla = row.get("libopendrive", {}), row.get("carla", {})
        cpp_text = (
            f"{'failed':>11} {'':>6} {'':>7} {'':>7}"
            if "error" in cpp
            else f"{cpp['matched']:>11} {cpp['over_1mm']:>6} {mm(cpp['p99_m']):>7} {mm(cpp['max_m']):>7}"
        )
        carla_text = (
            f"{'failed':>9} {'':>7} {'':>7} {'':>7} {'':>7}"
            if "error" in carla
            else f"{carla['waypoints']:>9} {mm(carla['median_m']):>7} {mm(carla.get('float32_median_m')):>7} "
            f"{mm(carla['p99_m']):>7} "
            f"{mm(carla['max_m']):>7}"
        )
        qc_text = " / ".join(
            "-" if not qc else "failed" if "error" in qc else f"{qc['total']} ({len(qc['skipped'])})"
            for qc in (row.get("asam_qc", {}), row.get("asam_qc_1.8", {}))
        )
        print(
            f"{row['what']:<30} {row['roads']:>5} {row['validate']['errors']:>6} "
            f"{row['validate']['warnings']:>5} | "
            f"{cpp_text} | {carla_text} | {qc_text}"
        )


def print_details(rows: dict) -> None:
    for row in rows.values():
        print(f"\n== {row['what']} ({row['xodr']}, made in {row['make_s']:.1f} s)")
        validate = row["validate"]
        print(
            "  validate errors:   "
            + (", ".join(f"{r} {n}" for r, n in validate["errors_by_rule"].items()) or "none")
        )
        print(
            "  validate warnings: "
            + (", ".join(f"{r} {n}" for r, n in validate["warnings_by_rule"].items()) or "none")
        )
        cpp = row.get("libopendrive", {})
        if "error" in cpp:
            print(f"  libOpenDRIVE: {cpp['error']}")
        else:
            worst = cpp.get("worst") or {}
            print(
                f"  libOpenDRIVE: {cpp['matched']} of {cpp['rows']} rows joined "
                f"({cpp['ours_unmatched']} of ours "
                f"unmatched), median {mm(cpp['median_m'])} mm, p99 {mm(cpp['p99_m'])} mm, max "
                f"{mm(cpp['max_m'])} mm at road {worst.get('road')} lane {worst.get('lane')} "
                f"s={worst.get('s')}; "
                f"{cpp['seconds']} s"
            )
        carla = row.get("carla", {})
        if "error" in carla:
            print(f"  CARLA: {carla['error']}")
        else:
            worst = carla.get("worst") or {}
            print(
                f"  CARLA: {carla['waypoints']} waypoints ({carla['unmatched']} without a lane of ours), "
                f"{carla['over_1cm']} more than 1 cm off; worst at road {worst.get('road')} lane "
                f"{worst.get('lane')} s={worst.get('s')}; {carla['seconds']} s"
            )
        for key, label in (("asam_qc", "ASAM"), ("asam_qc_1.8", "ASAM, header read as 1.8")):
            qc = row.get(key)
            if qc is None:
                continue
            if "error" in qc:
                print(f"  {label}: {qc['error']}")
                continue
            why = ", ".join(f"{n} {reason}" for reason, n in qc["skipped_why"].items()) or "none"
            print(
                f"  {label}: {qc['total']} issues, {qc['process']:.1f} s; {len(qc['skipped'])} of "
                f"{len(asam_qc.CHECKERS)} checkers skipped ({why})"
            )
            for checker, count in qc["issues"].items():
                print(f"      {count:>5}  {checker}: {qc['first'].get(checker, '')[:120]}")


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--only", help=f"comma-separated names: {', '.join(INPUTS)}")
    parser.add_argument("--keep", type=Path, help="build into (and reuse builds in) this folder")
    parser.add_argument("--no-install", action="store_true", help="do not make missing peers (report them)")
    parser.add_argument("--json", type=Path, help="also write the figures here")
    parser.add_argument(
        "--no-qc-1.8", dest="qc18", action="store_false",
        help="skip the ASAM run of the copy read as OpenDRIVE 1.8 (all checkers run: minutes on large maps)",
    )
    args = parser.parse_args()
    names = args.only.split(",") if args.only else list(INPUTS)
    unknown = [name for name in names if name not in INPUTS]
    if unknown:
        parser.error(f"unknown input {unknown[0]!r} (known: {', '.join(INPUTS)})")
    peers = get_peers(install=not args.no_install)
    for name, peer in peers.items():
        if isinstance(peer, str):
            print(f"peer {name} missing: {peer}", file=sys.stderr)
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.keep or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        rows = {}
        for name in names:
            what, source = INPUTS[name]
            print(f"{what} ...", file=sys.stderr)
            xodr, seconds = make_xodr(name, source, folder)
            qc_folder = Path(tmp) / f"qc-{name}"
            qc_folder.mkdir()
            rows[name] = {
                "what": what,
                "xodr": str(xodr),
                "make_s": seconds,
                **measure(xodr, qc_folder, peers, args.qc18),
            }
    print_table(rows)
    print_details(rows)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(rows, indent=2, default=str) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
