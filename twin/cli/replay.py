"""``twin replay``: show a recorded drive again, or re-simulate it and prove it comes out the same."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import click

from tavf_mapkit.cli.options import FORMAT_TO_JSON, Command


@click.command(cls=Command, renamed={"--out": "--output", "--format": FORMAT_TO_JSON},
               context_settings={"help_option_names": ["-h", "--help"]})
@click.argument("recording", type=click.Path(path_type=Path), metavar="SESSION.mcap")
@click.option("--resimulate", is_flag=True,
              help="Run the drive again with the recorded configuration, seeds and UDM answers and compare "
                   "every ego state (and /traffic message) with the recorded one. Exit 1 unless they are "
                   "identical.")
@click.option("--map", "map_dir", type=click.Path(path_type=Path), metavar="BUILD",
              help="The build to re-simulate on, if it moved since the recording (its map must be the same: "
                   "the OpenDRIVE sha256 is checked).")
@click.option("--keep", type=click.Path(path_type=Path), metavar="DIR",
              help="Keep the re-simulation's outputs (trajectory.csv, session.mcap, ...) in DIR.")
@click.option("--speed", type=click.FloatRange(min=0, min_open=True), metavar="X",
              help="Kinematic replay: print the states paced at X times real time (default: at once).")
@click.option("-o", "--output", "out_file", type=click.Path(dir_okay=False, path_type=Path), metavar="FILE.csv",
              help="Kinematic replay: write the trajectory CSV here instead of printing it.")
@click.option("--json", "as_json", is_flag=True,
              help="Print JSON for machines: the comparison (--resimulate), else a summary of the recording.")
def replay(recording: Path, resimulate: bool, map_dir: Path | None, keep: Path | None, speed: float | None,
           out_file: Path | None, as_json: bool) -> None:
    """Replay a drive recorded by `twin drive` (DIR/session.mcap).

    \b
    $ twin replay runs/ride/session.mcap -o replayed.csv
    $ twin replay runs/ride/session.mcap --speed 1          # states as they happened, in real time
    $ twin replay --resimulate runs/ride/session.mcap
    identical: 1201 of 1201 steps, max difference 0 (x y z yaw speed ...)

    The kinematic replay prints the recorded ego states (t, step, x, y, z, yaw, speed, lat, lon, road, lane;
    floats exactly as recorded). --resimulate re-runs the simulation: same map (sha256 checked), seed and
    options, with the recorded UDM answers delivered at the steps they arrived, and reports the largest
    difference per state field. A recording cut short (a killed drive) is compared as far as it goes.
    The format is described in docs/recording.md.
    """
    from twin.recording.reader import read_recording
    from twin.recording.replay import TRAJECTORY_COLUMNS, format_row, trajectory_rows
    from twin.recording.replay import resimulate as run_resimulation

    if resimulate:
        if speed is not None or out_file is not None:
            raise click.UsageError("--speed and -o/--output are for the kinematic replay, not --resimulate")
        comparison = run_resimulation(recording, map_dir=map_dir, keep=keep)
        report = comparison.as_dict()
        if as_json:
            click.echo(json.dumps(report, indent=2))
        else:
            verdict = "identical" if comparison.identical else "DIFFERENT"
            click.echo(f"{verdict}: {comparison.steps_compared} of {comparison.steps_recorded} recorded steps "
                       f"compared ({comparison.steps_resimulated} re-simulated), max difference "
                       f"{report['max_difference_overall']:.3g}")
            click.echo("  " + "  ".join(f"{name} {value:.3g}" for name, value in comparison.max_difference.items()))
            if comparison.first_difference_step is not None:
                click.echo(f"  first difference at step {comparison.first_difference_step}")
            if comparison.mismatched_identity:
                click.echo(f"  differing {comparison.mismatched_identity}")
            if comparison.traffic_recorded or comparison.traffic_resimulated:
                same = min(comparison.traffic_recorded, comparison.traffic_resimulated) - comparison.traffic_mismatched
                click.echo(f"  traffic: {same} of {comparison.traffic_recorded} recorded /traffic messages identical "
                           f"({comparison.traffic_resimulated} re-simulated)")
            if comparison.traffic_first_difference_step is not None:
                click.echo(f"  first traffic difference at step {comparison.traffic_first_difference_step}")
            if not comparison.recording_complete:
                click.echo("  note: the recording was cut short (no MCAP footer); compared as far as it goes")
        if not comparison.identical:
            sys.exit(1)
        return

    read = read_recording(recording)
    rows = list(trajectory_rows(read))
    if as_json and out_file is None and speed is None:
        first, last = rows[0], rows[-1]
        click.echo(json.dumps({"steps": len(rows), "t_start": first["t"], "t_end": last["t"],
                               "complete": read.complete, "config": read.config.get("config"),
                               "udm_answers": len(read.udm_responses), "metrics": read.metrics}, indent=2))
        return
    header = ",".join(TRAJECTORY_COLUMNS)
    if out_file is not None:
        from tavf_mapkit.fileutil import write_text_atomic

        write_text_atomic(out_file, "\n".join([header, *(format_row(row) for row in rows)]) + "\n")
        click.echo(f"{len(rows)} states, t {rows[0]['t']:.2f}..{rows[-1]['t']:.2f} s -> {out_file}"
                   + ("" if read.complete else " (recording cut short)"))
        return
    click.echo(header)
    start_wall, start_t = time.monotonic(), float(rows[0]["t"])
    for row in rows:
        if speed is not None:
            delay = (float(row["t"]) - start_t) / speed - (time.monotonic() - start_wall)
            if delay > 0:
                time.sleep(delay)
        click.echo(format_row(row))
