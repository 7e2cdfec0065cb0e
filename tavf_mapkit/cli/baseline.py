"""``mapkit baseline``: show the committed accuracy baselines, or refresh them (the only way they change)."""

from __future__ import annotations

import json
from pathlib import Path

import click

from tavf_mapkit.cli.lazy import LazyGroup
from tavf_mapkit.cli.options import FORMAT_TO_JSON, json_option


@click.group(cls=LazyGroup)
def baseline() -> None:
    """Accuracy baselines (tavf_mapkit/data/baselines/, package data) that CI compares new measurements with.

    \b
    $ mapkit baseline show
    $ mapkit baseline refresh --note "netconvert 1.28: junction shapes changed"
    """


@baseline.command(renamed={"--format": FORMAT_TO_JSON})
@click.option("--file", "path", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Baseline file (default: tavf_mapkit/data/baselines/accuracy.json of this package).")
@json_option
def show(path: Path | None, as_json: bool) -> None:
    """Print every measurement with its baseline values, tolerances and direction.

    \b
    $ mapkit baseline show
    $ mapkit baseline show --json | jq '.measurements | keys'
    """
    from tavf_mapkit.accuracy.baseline import BASELINE_FILE, load_baselines

    document = load_baselines(path or BASELINE_FILE)
    if as_json:
        click.echo(json.dumps(document, indent=2))
        return
    click.echo(f"mapkit {document.get('mapkit')}: {document.get('note') or ''}".rstrip(": "))
    for name, entry in document["measurements"].items():
        click.echo(f"\n{name}  ({entry['description']})")
        for metric, spec in entry["metrics"].items():
            click.echo(f"  {metric:<20} {spec['value']!s:>12}  +- {spec['tolerance']:<6} ({spec['better']} is better)")


@baseline.command()
@click.option("--shared", type=click.Path(file_okay=False, exists=True, path_type=Path), default=None,
              help="The real data folder (default: ../shared/data beside the checkout, or $TAVF_SHARED_DATA).")
@click.option("--work", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Where to build the inputs (default: a temporary folder).")
@click.option("--only", multiple=True, help="Refresh only these measurements (repeatable).")
@click.option("--note", default="", help="Why the baselines change (stored in the file).")
@click.option("--file", "path", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Baseline file to write (default: tavf_mapkit/data/baselines/accuracy.json).")
def refresh(shared: Path | None, work: Path | None, only: tuple[str, ...], note: str, path: Path | None) -> None:
    """Rebuild the real inputs with `mapkit build` (default stages), measure, and rewrite the baselines.

    \b
    $ mapkit baseline refresh --note "netconvert 1.28: junction shapes changed"
    $ mapkit baseline refresh --only compare/tavf-dlr/dlr-net --work /tmp/baseline --note "new lane widths"

    Tolerances and directions already in the file are kept; values are replaced. Commit the file with a
    message that says why it changed.
    """
    import os
    import tempfile

    from tavf_mapkit.accuracy.baseline import BASELINE_FILE, MEASUREMENTS, refreshed
    from tavf_mapkit.errors import InputError
    from tavf_mapkit.fileutil import write_text_atomic

    target = path or BASELINE_FILE
    unknown = [name for name in only if name not in MEASUREMENTS]
    if unknown:
        raise click.BadParameter(f"unknown measurement(s) {unknown}; known: {sorted(MEASUREMENTS)}",
                                 param_hint="--only")
    shared = shared or Path(os.environ.get("TAVF_SHARED_DATA", Path(__file__).resolve().parents[3] / "shared"
                                           / "data"))
    sources = {"jungfernstieg": shared / "hamburg" / "jungfernstieg_osm" / "jungfernstieg_2023-03-10.osm",
               "tavf-dlr": shared / "hamburg" / "tavf_dlr_sumo_net" / "network.net.xml.gz"}
    inputs = {"dlr_net": sources["tavf-dlr"], "ride": shared / "hamburg" / "gnss_ride_b4" / "thomas.json"}
    for file in (*sources.values(), *inputs.values()):
        if not file.is_file():
            raise InputError("missing real data file (give --shared)", file=str(file))
    previous = None
    if target.exists():
        previous = json.loads(target.read_text(encoding="utf-8"))
    names = list(only) or list(MEASUREMENTS)
    with tempfile.TemporaryDirectory() as temporary:
        folder = work or Path(temporary)
        for name, source in sources.items():
            if any(f"{name.replace('-', '_')}_xodr" in MEASUREMENTS[m].needs for m in names):
                out = folder / name
                click.echo(f"building {name} ...", err=True)
                _build(source, out)
                inputs[f"{name.replace('-', '_')}_xodr"] = out / f"{name}.xodr"
        measured: dict[str, dict] = {}
        for name in names:
            click.echo(f"measuring {name} ...", err=True)
            measured[name] = MEASUREMENTS[name].run(inputs)
    if previous and only:
        # keep the other measurements as they were
        kept = {n: {m: spec["value"] for m, spec in e["metrics"].items()}
                for n, e in previous["measurements"].items() if n not in measured and n in MEASUREMENTS}
        measured = {**kept, **measured}
    document = refreshed(measured, previous, note)
    write_text_atomic(target, json.dumps(document, indent=2) + "\n")
    click.echo(f"wrote {target}")


def _build(source: Path, out: Path) -> None:
    """The same build the tests make: ``mapkit build SOURCE -o OUT`` with the default stages."""
    from click.testing import CliRunner

    from tavf_mapkit.cli.main import cli
    from tavf_mapkit.errors import StageError

    result = CliRunner().invoke(cli, ["build", str(source), "-o", str(out), "-q"])
    if result.exit_code != 0:
        raise StageError(f"building {source.name} failed: {result.output.strip().splitlines()[-1:]}")
