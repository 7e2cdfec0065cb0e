"""Options shared by several subcommands (the rasterio ``rio/options.py`` pattern)."""

from __future__ import annotations

import functools
import logging
from pathlib import Path

import click

from tavf_mapkit.errors import InputError


class BBoxType(click.ParamType):
    """``W,S,E,N`` in degrees -> an Area; a malformed box is a usage error (exit code 2)."""

    name = "W,S,E,N"

    def convert(self, value, param, ctx):
        from tavf_mapkit.osm.area import Area, parse_bbox

        if isinstance(value, Area):
            return value
        try:
            return parse_bbox(value)
        except InputError as error:
            self.fail(error.message, param, ctx)


bbox_option = click.option(
    "--bbox", type=BBoxType(), default=None,
    help="Area to keep: west,south,east,north in degrees (e.g. 9.95,53.543,10.01,53.57).",
)
polygon_option = click.option(
    "--polygon", type=click.Path(dir_okay=False, path_type=Path), default=None, metavar="AREA.geojson",
    help="Area to keep: a GeoJSON file with Polygon/MultiPolygon geometries (lon/lat).",
)
json_option = click.option("--json", "as_json", is_flag=True, help="Print JSON for machines instead of text.")
output_option = click.option("-o", "--output", default="-", show_default=True,
                             help="Output file, or - for standard output.")
step_option = click.option("--step", type=click.FloatRange(min=0.001), default=0.5, show_default=True,
                           help="Sampling step along s in metres.")


def xodr_argument(name: str = "xodr"):
    return click.argument(name, type=click.Path(dir_okay=False, path_type=str))


def area_from(bbox, polygon: Path | None):
    """The Area of --bbox or --polygon (at most one), or None for the whole file."""
    if bbox is not None and polygon is not None:
        raise click.UsageError("give --bbox or --polygon, not both")
    if polygon is not None:
        from tavf_mapkit.osm.area import load_polygon

        return load_polygon(polygon)
    return bbox


# -- verbosity: -v/-q belong to the group, which configures logging once for every subcommand ----------------

_VERBOSITY = "tavf.verbosity"  # key in click's ctx.meta, which the group's context shares with its subcommands
_VERBOSITY_AFTER = "tavf.verbosity-after"  # -v/-q typed after the subcommand (VerbosityAnywhere)
_LEVELS = {-1: logging.ERROR, 0: logging.WARNING, 1: logging.INFO, 2: logging.DEBUG}


def verbosity_options(group_function):
    """``-v/--verbose`` and ``-q/--quiet`` (counted, as rasterio's ``rio -v``) on a command group."""

    @click.option("-v", "--verbose", count=True, help="Log more: -v info, -vv debug.")
    @click.option("-q", "--quiet", count=True,
                  help="Log errors only, and no progress lines (same as the -q of build and sweep).")
    @functools.wraps(group_function)
    def group(verbose: int, quiet: int, **kwargs):
        set_verbosity(verbose - quiet + click.get_current_context().meta.pop(_VERBOSITY_AFTER, 0))
        return group_function(**kwargs)

    return group


def set_verbosity(verbosity: int) -> None:
    """Remember the verbosity for the subcommands and set the log level (one place for the whole CLI)."""
    click.get_current_context().meta[_VERBOSITY] = verbosity
    # basicConfig is a no-op when the host (pytest, an embedding program) already set logging up
    logging.basicConfig(format="%(levelname)s %(name)s: %(message)s")
    logging.getLogger().setLevel(log_level(verbosity))


def verbosity() -> int:
    """The group's -v count minus its -q count (0 when a command runs without its group, as in some tests)."""
    ctx = click.get_current_context(silent=True)
    return ctx.meta.get(_VERBOSITY, 0) if ctx is not None else 0


def log_level(verbosity: int) -> int:
    return _LEVELS[max(-1, min(2, verbosity))]


# -- the spellings of the previous release, understood for one more with a note on stderr --------------------

#: ``--format text|json`` became ``--json`` (``--format`` is for file formats only)
FORMAT_TO_JSON = {"json": ("--json",), "text": ()}


class Command(click.Command):
    """A command that still understands options renamed in the last release.

    ``renamed`` maps an old option to its new spelling, or (for an old option with a value) to a dict from
    the old value to the tokens that replace option and value (``FORMAT_TO_JSON``). The arguments are
    rewritten before click parses them, so the old spellings are in no --help; each one used prints one line.
    """

    def __init__(self, *args, renamed: dict[str, str | dict[str, tuple[str, ...]]] | None = None, **kwargs):
        super().__init__(*args, **kwargs)
        self.renamed = dict(renamed or {})

    def parse_args(self, ctx: click.Context, args: list[str]) -> list[str]:
        if self.renamed:
            args = respelled(args, self.renamed, ctx.command_path)
        return super().parse_args(ctx, args)


class VerbosityAnywhere(click.Group):
    """A group whose -v/-q may also follow the subcommand (``mapkit validate -q map.xodr``), as users type it.

    The tokens are taken out of the subcommand's arguments and added to the group's count, so logging is still
    configured once, here; a subcommand with its own -q/--quiet (build, sweep) keeps it.
    """

    def resolve_command(self, ctx: click.Context, args: list[str]):
        name, command, rest = super().resolve_command(ctx, args)
        if command is not None and not isinstance(command, click.Group):
            rest, change = verbosity_tokens(rest, own={n for p in command.params for n in getattr(p, "opts", ())})
            # click resolves the subcommand before it runs the group's callback, which sets the level
            ctx.meta[_VERBOSITY_AFTER] = change
        return name, command, rest


def verbosity_tokens(args: list[str], own: set[str]) -> tuple[list[str], int]:
    """(``args`` without the -v/-vv/--verbose/-q/--quiet tokens the command does not define itself, their count:
    +1 per v, -1 per q). Nothing after ``--`` is touched."""
    kept: list[str] = []
    change = 0
    for index, token in enumerate(args):
        if token == "--":
            kept += args[index:]
            break
        if token in own:
            kept.append(token)
        elif token in ("--verbose", "--quiet"):
            change += 1 if token == "--verbose" else -1
        elif len(token) > 1 and token[0] == "-" and set(token[1:]) <= {"v"} and "-v" not in own:
            change += len(token) - 1
        elif len(token) > 1 and token[0] == "-" and set(token[1:]) <= {"q"} and "-q" not in own:
            change -= len(token) - 1
        else:
            kept.append(token)
    return kept, change


class Group(VerbosityAnywhere):
    """A group whose subcommands (made with ``@group.command()``) are :class:`Command` s."""

    command_class = Command


def respelled(args: list[str], renamed: dict, where: str) -> list[str]:
    """``args`` with the old spellings in ``renamed`` replaced by the new ones (a note on stderr for each)."""
    out: list[str] = []
    tokens = iter(args)
    for token in tokens:
        if token == "--":  # the rest are arguments, whatever they look like
            out += [token, *tokens]
            break
        name, equals, value = token.partition("=")
        new = renamed.get(name)
        if new is None:
            out.append(token)
        elif isinstance(new, str):
            click.echo(f"{where}: {name} is deprecated, use {new} (the old spelling goes in the next release)",
                       err=True)
            out.append(new + equals + value)
        else:
            if not equals:
                value = next(tokens, None)
            if value not in new:  # not an old spelling after all: let click say what is wrong
                out += [token] if equals or value is None else [token, value]
                continue
            instead = " ".join(new[value]) or "nothing (the default)"
            click.echo(f"{where}: {name} {value} is deprecated, use {instead} (the old spelling goes in the next "
                       "release)", err=True)
            out += new[value]
    return out
