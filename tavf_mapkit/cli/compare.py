"""``mapkit compare``: how far a built OpenDRIVE network is from a reference network."""

from __future__ import annotations

import json
from pathlib import Path

import click

from tavf_mapkit.cli.options import FORMAT_TO_JSON, BBoxType, Command


def format_comparison(report: dict) -> str:
    def shares(values):
        return "  ".join(f"{k} m: {100 * v:5.1f} %" if v is not None else f"{k} m: -" for k, v in values.items())

    offset, fit, topology = report["offset"], report["fitted_transform"], report["topology"]
    lines = [
        f"build      {report['build']}",
        f"reference  {report['reference']} ({report['reference_kind']})",
        (f"overlap    {report['overlap']['area_km2']:.3f} km2, driving lanes {report['lengths_m']['build']:.0f} m "
        f"(build) / {report['lengths_m']['reference']:.0f} m (reference)"),
        (f"offset     median {offset['median_m']} m, mean {offset['mean_m']} m, p95 {offset['p95_m']} m "
        f"({100 * (offset['paired_fraction'] or 0):.1f} % of the build's lanes paired within "
        f"{offset['pair_distance_m']:g} m)"),
        f"hausdorff  lanes {report['hausdorff_m']['lanes']} m, roads {report['hausdorff_m']['roads']} m",
        f"precision  {shares(report['precision'])}",
        f"recall     {shares(report['recall'])}",
    ]
    if fit:
        lines.append(f"transform  build is {fit['dx']:+.3f} m east, {fit['dy']:+.3f} m north, rotated "
                     f"{fit['rotation_deg']:+.4f} deg, scale {fit['scale']:.6f} relative to the reference "
                     f"(residual {fit['residual_rms_m']} m over {fit['pairs']} samples)")
    else:
        lines.append("transform  not enough paired lanes to fit one")
    lines.append(f"topology   junctions {topology['junctions']['build']} / {topology['junctions']['reference']}, "
                 f"largest strongly connected share {topology['largest_scc_share']['build']} / "
                 f"{topology['largest_scc_share']['reference']} (build / reference)")
    for lane_type, figures in report["by_lane_type"].items():
        if lane_type != "driving" and figures["precision"] is not None:
            lines.append(f"{lane_type:<10} precision@2m {figures['precision']['2']}, recall@2m {figures['recall']['2']}")
    return "\n".join(lines)


@click.command(cls=Command, renamed={"--format": FORMAT_TO_JSON, "--area": "--polygon"})
@click.argument("build", metavar="BUILD.xodr", type=click.Path(dir_okay=False, path_type=str))
@click.argument("reference", type=click.Path(dir_okay=False, path_type=str))
@click.option("--bbox", type=BBoxType(), default=None, help="Only compare inside west,south,east,north (degrees).")
@click.option("--polygon", type=click.Path(dir_okay=False, path_type=Path), default=None, metavar="AREA.geojson",
              help="Only compare inside the polygons of a GeoJSON file (lon/lat).")
@click.option("--json", "as_json", is_flag=True,
              help="Print JSON for machines instead of text (contract in docs/accuracy.md).")
@click.option("--plot", type=click.Path(dir_okay=False, path_type=Path), default=None, metavar="OUT.png",
              help="Also draw the build's lanes coloured by their distance to the reference.")
@click.option("--step", type=click.FloatRange(min=0.05), default=1.0, show_default=True,
              help="Sampling step along the lane centre lines (m).")
@click.option("-o", "--output", default="-", show_default=True, help="Write the report here instead of stdout.")
def compare(build: str, reference: str, bbox, polygon: Path | None, as_json: bool, plot: Path | None, step: float,
            output: str) -> None:
    """Compare BUILD.xodr with a REFERENCE network (.xodr, .net.xml or .net.xml.gz) where both have roads.

    \b
    $ mapkit compare build/tavf/tavf.xodr ../shared/data/hamburg/tavf_dlr_sumo_net/network.net.xml.gz
    $ mapkit compare build/a/a.xodr lgv.xodr --bbox 9.95,53.543,10.01,53.57 --plot compare.png
    $ mapkit compare build/a/a.xodr ref.xodr --json | jq .fitted_transform

    Both networks go through their own georeference into one metric CRS. Reported: Hausdorff
    distance of lane and road centre lines, offset (mean, median, p95) of paired lane centre lines,
    length precision/recall within 0.5/1/2/3/5 m per lane type, the similarity transform (dx east,
    dy north, rotation, scale) of BUILD relative to REFERENCE -- a systematic georeference error
    shows here -- and junction counts and connectivity. Exit code 2 if a file cannot be read or
    the networks do not overlap.
    """
    from tavf_mapkit.accuracy.compare import compare_networks
    from tavf_mapkit.cli.options import area_from

    region = area_from(bbox, polygon)
    comparison = compare_networks(build, reference, area=region, step=step)
    if plot is not None:
        from tavf_mapkit.accuracy.plot import plot_comparison

        plot_comparison(comparison, plot)
    report = comparison.to_dict()
    text = json.dumps(report, indent=2) + "\n" if as_json else format_comparison(report) + "\n"
    if output == "-":
        click.echo(text, nl=False)
    else:
        from tavf_mapkit.fileutil import write_text_atomic

        write_text_atomic(output, text)
