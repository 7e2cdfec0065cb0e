"""``mapkit``: build driving-simulation worlds from OSM, SUMO and OpenDRIVE.

Each subcommand lives in its own module; add one by adding a line to COMMANDS.
"""

from __future__ import annotations

import click

from tavf_mapkit import __version__
from tavf_mapkit.cli.lazy import LazyGroup
from tavf_mapkit.cli.options import verbosity_options

COMMANDS = {
    "info": "tavf_mapkit.cli.info:info",
    "export": "tavf_mapkit.cli.export:export",
    "extract": "tavf_mapkit.cli.extract:extract",
    "build": "tavf_mapkit.cli.build:build",
    "mesh": "tavf_mapkit.cli.mesh:mesh",
    "validate": "tavf_mapkit.cli.validate:validate",
    "compare": "tavf_mapkit.cli.compare:compare",
    "match-trace": "tavf_mapkit.cli.match_trace:match_trace",
    "baseline": "tavf_mapkit.cli.baseline:baseline",
    "view": "tavf_mapkit.cli.view:view",
}


@click.group(cls=LazyGroup, lazy_commands=COMMANDS, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="mapkit")
@verbosity_options
def cli() -> None:
    """Turn real city map data into a driving-simulation world.

    \b
    $ mapkit build osm-extract.osm          # OSM -> OpenDRIVE -> meshes -> collision world
    $ mapkit info build/tavf/tavf.xodr      # what an OpenDRIVE file holds, and where on Earth
    $ mapkit export map.xodr --layer lane-border --format csv -o borders.csv
    $ mapkit validate map.xodr --json | jq .summary

    Every command writes its output where -o/--output says and prints JSON for machines with --json
    (--format names a file format); -v/-q (before or after the command) set how much it logs.
    """


if __name__ == "__main__":
    cli()
