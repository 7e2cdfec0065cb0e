"""``mapkit info``: what an OpenDRIVE file holds and where on Earth it is."""

from __future__ import annotations

import json

import click

from tavf_mapkit.cli.options import json_option, xodr_argument


@click.command()
@xodr_argument()
@json_option
def info(xodr: str, as_json: bool) -> None:
    """Summarise an OpenDRIVE file: version, counts, length, bounds, georeference.

    \b
    $ mapkit info build/tavf/tavf.xodr
    $ mapkit info map.xodr --json | jq .georeference.bounds_wgs84

    The georeference is checked for plausibility (bounds inside the CRS's area of use, no
    self-contradiction such as a UTM zone that does not contain +lon_0). Exit code 2 if the file
    cannot be read.
    """
    from tavf_mapkit.opendrive.snapshot import load_build_map  # the build's snapshot when the file has one
    from tavf_mapkit.opendrive.summary import format_summary, summarise

    summary = summarise(load_build_map(xodr))
    if as_json:
        click.echo(json.dumps(summary, indent=2))
    else:
        click.echo(format_summary(summary))
