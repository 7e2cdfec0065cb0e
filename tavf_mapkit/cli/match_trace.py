"""``mapkit match-trace``: map-match a GNSS recording to the lanes of a map and report the distances."""

from __future__ import annotations

import json
from pathlib import Path

import click

from tavf_mapkit.cli.options import FORMAT_TO_JSON, Command


def format_match(stats: dict) -> str:
    if not stats["matched"]:
        return (f"{stats['fixes']} fixes, none within {stats['radius_m']} m of a lane: "
                "is the trace on this map (and the map's georeference right)?")
    return "\n".join([
        (f"fixes      {stats['fixes']}, matched {stats['matched']} ({100 * stats['matched_fraction']:.1f} %, "
        f"within {stats['radius_m']:g} m of a lane)"),
        (f"distance   median {stats['median_m']} m, mean {stats['mean_m']} m, p95 {stats['p95_m']} m "
        f"(to the matched lane's centre line)"),
        (f"floor      mean {stats['floor_mean_m']} m, median {stats['floor_median_m']} m (same fixes to the nearest "
        f"lane centre line; GNSS sigma assumed {stats['sigma_m']} m)"),
        (f"route      {stats['route_lanes']} lanes, {stats['route_breaks']} breaks, {stats['jumps']} jumps "
        "(moves no car may make)"),
    ])


@click.command("match-trace", cls=Command, renamed={"--format": FORMAT_TO_JSON})
@click.argument("map_path", metavar="MAP.xodr", type=click.Path(dir_okay=False, path_type=str))
@click.argument("trace", type=click.Path(path_type=Path))
@click.option("--json", "as_json", is_flag=True,
              help="Print JSON for machines instead of text (contract in docs/accuracy.md).")
@click.option("--lane-types", default="driving", show_default=True,
              help="Comma-separated OpenDRIVE lane types to match to (e.g. driving,biking).")
@click.option("--sigma", type=click.FloatRange(min=0.1), default=None,
              help="GNSS noise in metres (default: the trace's median reported accuracy, else 5).")
@click.option("--radius", type=click.FloatRange(min=1.0), default=None,
              help="Fixes farther than this from every lane stay unmatched (default max(20, 4 sigma)).")
@click.option("--fixes", type=click.Path(dir_okay=False, path_type=Path), default=None, metavar="OUT.csv",
              help="Also write every fix with its matched road, lane, s, t and distances.")
@click.option("--plot", type=click.Path(dir_okay=False, path_type=Path), default=None, metavar="OUT.png",
              help="Also draw the fixes coloured by their distance to the matched lane.")
@click.option("-o", "--output", default="-", show_default=True, help="Write the report here instead of stdout.")
def match_trace(map_path: str, trace: Path, as_json: bool, lane_types: str, sigma: float | None, radius: float | None,
                fixes: Path | None, plot: Path | None, output: str) -> None:
    """Map-match TRACE to the lanes of MAP.xodr and report how far the fixes are from them.

    \b
    $ mapkit match-trace build/tavf-dlr/tavf-dlr.xodr ../shared/data/hamburg/gnss_ride_b4/thomas.json
    $ mapkit match-trace map.xodr ride.gpx --json | jq .median_m
    $ mapkit match-trace map.xodr drive.bag --fixes fixes.csv --plot match.png

    TRACE: GPX, GeoJSON (points or lines), CSV (lat,lon[,time], header detected), the JSON ride
    format of ../shared/data/hamburg/gnss_ride_b4, or a ROS 1/ROS 2 bag with sensor_msgs/NavSatFix
    or sbg_driver/SbgGpsPos. The matcher is an HMM over candidate lanes (distance, heading, route
    distance through the lane graph). floor_mean_m is the mean distance of the same fixes to the
    nearest lane centre line: what no map can beat. Exit code 2 for unreadable or empty traces.
    """
    from tavf_mapkit.accuracy.matching import match_trace as run
    from tavf_mapkit.lanegraph import LaneGraph
    from tavf_mapkit.opendrive.snapshot import load_build_map  # the build's snapshot when the file has one
    from tavf_mapkit.traces import read_trace

    odr = load_build_map(map_path)
    recording = read_trace(trace)
    types = tuple(t.strip() for t in lane_types.split(",") if t.strip())
    graph = LaneGraph.from_opendrive(odr, lane_types=types)
    result = run(odr, recording, graph, sigma_m=sigma, radius_m=radius, lane_types=types)
    stats = {"map": map_path, "trace": str(trace), "trace_format": recording.source_format, **result.stats()}
    if fixes is not None:
        write_fixes_csv(result, recording, fixes)
    if plot is not None:
        from tavf_mapkit.accuracy.plot import plot_match

        plot_match(result, graph, plot, title=f"{trace.name} on {Path(map_path).name}: fixes by distance to the "
                                             "matched lane (m); unmatched: x")
    text = json.dumps(stats, indent=2) + "\n" if as_json else format_match(stats) + "\n"
    if output == "-":
        click.echo(text, nl=False)
    else:
        from tavf_mapkit.fileutil import write_text_atomic

        write_text_atomic(output, text)


def write_fixes_csv(result, recording, path: Path) -> None:
    import csv
    import io
    import math

    from tavf_mapkit.fileutil import write_text_atomic

    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(["fix", "t", "lat", "lon", "x", "y", "matched", "road", "lane", "s", "t_lateral", "distance_m",
                     "floor_m"])
    for i in range(len(result)):
        def number(value, digits=3):
            return "" if math.isnan(value) else f"{value:.{digits}f}"

        writer.writerow([i, number(recording.t[i]), f"{recording.lat[i]:.8f}", f"{recording.lon[i]:.8f}",
                         number(result.x[i]), number(result.y[i]), int(result.matched[i]), result.road_id[i],
                         int(result.lane_id[i]) if result.matched[i] else "", number(result.s[i]),
                         number(result.t[i]), number(result.distance_m[i]), number(result.floor_m[i])])
    write_text_atomic(path, buffer.getvalue())
