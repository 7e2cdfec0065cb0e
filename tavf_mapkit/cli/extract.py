"""``mapkit extract``: cut an area out of an OSM file with complete ways."""

from __future__ import annotations

import json
from pathlib import Path

import click

from tavf_mapkit.cli.options import area_from, bbox_option, json_option, polygon_option


@click.command(short_help="Cut an area out of an OSM file (.osm, .osm.pbf, .osm.gz, .osm.bz2).")
@click.argument("input_path", metavar="INPUT", type=click.Path(path_type=Path))
@bbox_option
@polygon_option
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="OSM file to write; the format follows the name (.osm, .osm.pbf, .osm.gz, .osm.bz2).")
@click.option("--routes/--no-routes", default=False, show_default=True,
              help="Also keep route relations (bus and tram lines); turn restrictions are always kept.")
@json_option
def extract(input_path: Path, bbox, polygon: Path | None, output: Path, routes: bool, as_json: bool) -> None:
    """Cut an area out of an OSM file, keeping every way that enters it whole.

    \b
    $ mapkit extract hamburg-latest.osm.pbf --bbox 9.95,53.543,10.01,53.57 -o tavf.osm
    $ mapkit extract city.osm.pbf --polygon district.geojson -o district.osm --json

    A way with at least one node inside the area is kept with all its nodes; turn restrictions that
    touch kept ways are kept too. Without --bbox/--polygon the whole file is re-written, which is how
    `mapkit build` sanitises its input: osmium refuses XML entity declarations and writes plain OSM XML.
    An extract with no ways is refused (exit code 2).
    """
    from tavf_mapkit.osm.extract import extract as run_extract

    area = area_from(bbox, polygon)
    summary = run_extract(input_path, output, area, routes=routes)
    if as_json:
        click.echo(json.dumps(summary.to_dict(), indent=2))
    else:
        click.echo(summary.to_text())
