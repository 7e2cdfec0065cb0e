"""``mapkit build``: OSM, a SUMO network or OpenDRIVE -> a build folder (OpenDRIVE, SUMO net, meshes, report)."""

from __future__ import annotations

import json
import shlex
import sys
from contextlib import ExitStack
from pathlib import Path

import click

from tavf_mapkit.cli.options import area_from, bbox_option, json_option, polygon_option, verbosity
from tavf_mapkit.cluster import check_cluster_options, wants_cluster
from tavf_mapkit.progress import progress_line


@click.command(short_help="Build a simulation world from OSM, a SUMO network or OpenDRIVE.")
@click.argument("input_path", metavar="INPUT", type=click.Path(path_type=Path))
@click.option("--pipeline", "pipeline_file", type=click.Path(dir_okay=False, path_type=Path), default=None,
              metavar="PIPELINE.toml", help="Pipeline file (stages, area, profile, stage options).")
@bbox_option
@polygon_option
@click.option("--profile", default=None, metavar="carla|full|FILE.toml",
              help="netconvert option profile (default: the pipeline's, else carla).")
@click.option("--crs", type=click.Choice(["tmerc", "utm", "keep"]), default=None,
              help="Projection: tmerc centred on the data (default), utm, or keep a SUMO network's own.")
@click.option("--driving-side", type=click.Choice(["auto", "left", "right"], case_sensitive=False), default=None,
              help="Side traffic keeps to. auto (default): from the country the map lies in (offline lookup), a "
                   "SUMO network's lefthand flag, or an OpenDRIVE file's road rule.")
@click.option("-o", "--output", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Build folder (default: build/NAME, NAME from the pipeline or the input file).")
@click.option("--no-repair", "no_repair", is_flag=True,
              help="Keep netconvert's OpenDRIVE as written, for comparison ([opendrive] repair = false); only "
                   "geometry no build can use (vertices off Earth, absurd lengths) is still repaired.")
@click.option("--force", is_flag=True, help="Rerun every stage even if its inputs and options are unchanged.")
@click.option("--workers", type=int, default=None, metavar="N",
              help="Run the tile stages (mesh, collision) on a local Dask cluster of N processes (N > 1; 1: this "
                   "process). The build is byte-identical to a single-process one. Needs tavf-mapkit[distributed].")
@click.option("--scheduler", default=None, metavar="tcp://HOST:PORT",
              help="Run the tile stages on the workers of a running Dask scheduler (no shared filesystem needed; "
                   "docs/distributed.md).")
@click.option("-q", "--quiet", is_flag=True,
              help="No progress lines (on a terminal, long stages otherwise show units done and time left); "
                   "`mapkit -q build` too.")
@json_option
def build(input_path: Path, pipeline_file: Path | None, bbox, polygon: Path | None, profile: str | None,
          crs: str | None, driving_side: str | None, output: Path | None, no_repair: bool, force: bool,
          workers: int | None, scheduler: str | None, quiet: bool, as_json: bool) -> None:
    """Build a driving-simulation world from OSM, a SUMO network or an OpenDRIVE file.

    \b
    $ mapkit build sample_data/tavf_synthetic.osm
    $ mapkit build hamburg.osm.pbf --pipeline pipelines/tavf.toml -o build/tavf
    $ mapkit build network.net.xml.gz --profile full --crs keep --json
    $ mapkit build Town04.xodr -o build/town04
    $ mapkit build london.osm.pbf --driving-side left
    $ mapkit build network.net.xml.gz -o build/raw --no-repair
    $ mapkit build maribor.osm.gz --workers 2
    $ mapkit build region.osm.pbf --scheduler tcp://10.0.0.5:8786

    \b
    Stages: extract -> netconvert -> opendrive -> mesh -> collision -> check -> report
    (stages not installed yet are skipped with a note; an OpenDRIVE input starts at opendrive,
    and its build has no SUMO network). The build folder holds NAME.xodr,
    NAME.net.xml, mesh/, collision/, report/, logs/ and manifest.json (docs/build-folder.md).
    It is built next to the target and swapped in when complete: a failed or interrupted build
    leaves an existing build untouched. Stages whose inputs and options did not change since the
    last build are reused (--force reruns them).

    \b
    Exit codes: 0 ok, 1 a stage failed, 2 bad input or options, 130 interrupted.
    """
    from tavf_mapkit.pipeline.config import load_pipeline
    from tavf_mapkit.pipeline.runner import run_build
    from tavf_mapkit.pipeline.summary import render_summary

    quiet = quiet or verbosity() < 0
    area = area_from(bbox, polygon)
    side = driving_side.lower() if driving_side else None
    repair = False if no_repair else None  # None: the pipeline's [opendrive] repair (default true)
    config = load_pipeline(pipeline_file)
    if area is not None:
        if area.polygon is not None:
            config = config.with_overrides(polygon=polygon, profile=profile, crs=crs,
                                          driving_side=side, repair=repair)
        else:
            config = config.with_overrides(bbox=area.bbox, profile=profile, crs=crs,
                                          driving_side=side, repair=repair)
    else:
        config = config.with_overrides(profile=profile, crs=crs, driving_side=side, repair=repair)

    # on a terminal, long stages also show units done, elapsed and time left on one self-overwriting line;
    # never with -q or --json, nor into a file or pipe (tavf_mapkit/progress.py)
    live = progress_line(sys.stderr, quiet=quiet, as_json=as_json)

    def notice(line: str) -> None:
        if live is not None:
            live.print(line)  # the live line makes room for it
        else:
            click.echo(line, err=True)

    def progress(line: str) -> None:
        if not quiet:
            notice(line)

    command = shlex.join(["mapkit", *sys.argv[1:]]) if sys.argv and sys.argv[0].endswith("mapkit") else None
    check_cluster_options(workers, scheduler)
    try:
        with ExitStack() as stack:
            fanout = None
            if wants_cluster(workers, scheduler):  # else Dask is never imported
                from tavf_mapkit.cluster import connect

                fanout = stack.enter_context(connect(workers=workers, scheduler=scheduler))
            result = run_build(input_path, config, output, force=force, progress=progress, command=command,
                               notice=notice, meter=live.task if live is not None else None, fanout=fanout)
    finally:
        if live is not None:
            live.clear()  # an error or the summary starts on a clean line
    if as_json:
        click.echo(json.dumps(_json_summary(result), indent=2))
    else:
        click.echo(render_summary(result.manifest, result.folder))


def _json_summary(result) -> dict:
    manifest = result.manifest
    report_path = result.folder / "report" / "summary.json"
    report = json.loads(report_path.read_text(encoding="utf-8")) if report_path.is_file() else None
    return {
        "folder": str(result.folder),
        "status": manifest["status"],
        "seconds": manifest["seconds"],
        "stages": [{key: record.get(key) for key in ("name", "status", "seconds", "note")}
                   for record in manifest["stages"]],
        "outputs": {artifact: str(result.folder / info["path"])
                    for artifact, info in manifest["artifacts"].items()},
        "georeference": manifest.get("georeference"),
        "attribution": manifest.get("attribution"),
        "report": report,
    }
