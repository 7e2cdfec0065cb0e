"""``twin``: drive a simulated test vehicle through a mapkit build and talk to an Urban Dynamic Map."""

from __future__ import annotations

import click

from tavf_mapkit.cli.lazy import LazyGroup
from tavf_mapkit.cli.options import verbosity_options
from twin import __version__

COMMANDS = {
    "udm": "twin.cli.udm:udm",
    "drive": "twin.cli.drive:drive",
    "replay": "twin.cli.replay:replay",
    "sweep": "twin.cli.sweep:sweep",
}


@click.group(cls=LazyGroup, lazy_commands=COMMANDS, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="twin")
@verbosity_options
def cli() -> None:
    """Drive a simulated vehicle through a mapkit build.

    \b
    $ twin drive --map build/sample --random --duration 60
    $ twin udm serve --port 8765 --map build/sample
    $ twin -v drive --map build/sample --random -o runs/sample --json

    Every command writes its output where -o/--output says and prints JSON for machines with --json;
    -v/-q (before or after the command) set how much it logs.
    """


if __name__ == "__main__":
    cli()
