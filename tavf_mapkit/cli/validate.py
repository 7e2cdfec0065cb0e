"""``mapkit validate``: what is wrong in an OpenDRIVE file, and where."""

from __future__ import annotations

import json
import sys

import click

from tavf_mapkit.cli.options import FORMAT_TO_JSON, Command, xodr_argument


@click.command(cls=Command, renamed={"--format": FORMAT_TO_JSON})
@xodr_argument()
@click.option("--json", "as_json", is_flag=True,
              help="Print JSON for machines instead of text (the contract in docs/validation-rules.md).")
@click.option("--rules", default=None, metavar="IDS",
              help="Comma-separated rule ids or families to run (e.g. geometry,topology.contact-gap). Default: all.")
@click.option("--strict", is_flag=True, help="Treat warnings as errors (exit code 1 on any warning).")
@click.option("--schema-dir", type=click.Path(file_okay=False, exists=True), default=None,
              help="Folder with the official OpenDRIVE XSDs (layout of asam-qc-opendrive's schema/ folder); "
                   "default: $MAPKIT_OPENDRIVE_XSD or an installed asam-qc-opendrive.")
@click.option("--limit", type=click.IntRange(min=0), default=50, show_default=True,
              help="Findings to print as text (0: all; --json has them all).")
@click.option("--no-info", is_flag=True, help="Leave notes (severity info, e.g. dead ends) out of the text output.")
@click.option("-o", "--output", default="-", show_default=True, help="Write the report here instead of stdout.")
def validate(xodr: str, as_json: bool, rules: str | None, strict: bool, schema_dir: str | None, limit: int,
             no_info: bool, output: str) -> None:
    """Check an OpenDRIVE file against the rule catalogue: structure, geometry, topology, georeference.

    \b
    $ mapkit validate build/tavf/tavf.xodr
    $ mapkit validate map.xodr --rules geometry,topology.contact-gap
    $ mapkit validate map.xodr --json | jq '.findings[] | select(.severity=="error")'
    $ mapkit validate map.xodr --strict && echo "no errors, no warnings"

    Every finding names its rule, severity, road, lane, s and line. The catalogue (id, severity,
    tolerance, why it matters) is docs/validation-rules.md. Exit code 0: no errors; 1: errors found
    (with --strict also warnings); 2: the file cannot be read (missing, not XML).
    """
    from tavf_mapkit.validate import validate_file

    try:
        report = validate_file(xodr, rules=rules, strict=strict, schema_dir=schema_dir)
    except ValueError as error:
        raise click.BadParameter(str(error), param_hint="--rules") from None
    if as_json:
        text = json.dumps(report.to_dict(), indent=2) + "\n"
    else:
        text = report.format_text(limit=limit or None, show_info=not no_info) + "\n"
    if output == "-":
        click.echo(text, nl=False)
    else:
        from tavf_mapkit.fileutil import write_text_atomic

        write_text_atomic(output, text)
    sys.exit(report.exit_code)
