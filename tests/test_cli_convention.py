"""One convention for both command lines (`mapkit`, `twin`), checked on every command the click groups hold.

The commands are found by walking the click objects, so a new command is checked the day it is added:
-o/--output names the output path, --json asks for machine-readable output (--format is only ever a file
format), --seed is an integer, a build folder is --map (twin) or the BUILD argument (mapkit), -v/-q belong to
the group (logging is configured once, there), and every --help starts with an example of that very command.
"""

from __future__ import annotations

import logging

import click
import pytest
from click.testing import CliRunner

from tavf_mapkit.cli.main import cli as mapkit_cli
from twin.cli.main import cli as twin_cli

GROUPS = {"mapkit": mapkit_cli, "twin": twin_cli}

#: commands that print no report, so --json would have nothing to say (and why)
NO_REPORT = {
    "mapkit baseline refresh": "rewrites the baseline file and prints only its name",
}


def _walk(name: str, command: click.Command, parent: click.Context | None = None):
    """(command path, command) for the group and everything under it, depth first."""
    ctx = click.Context(command, info_name=name, parent=parent)
    yield ctx.command_path, command
    if isinstance(command, click.Group):
        for child in command.list_commands(ctx):
            yield from _walk(child, command.get_command(ctx, child), ctx)


COMMANDS = [pair for root, group in GROUPS.items() for pair in _walk(root, group)]
LEAVES = [(path, command) for path, command in COMMANDS if not isinstance(command, click.Group)]


def _options(command: click.Command) -> list[click.Option]:
    return [param for param in command.params if isinstance(param, click.Option)]


def _ids(pairs):
    return [path for path, _ in pairs]


def test_the_walk_finds_every_command():
    paths = set(_ids(COMMANDS))
    assert {"mapkit build", "mapkit baseline show", "mapkit view", "twin drive", "twin udm serve",
            "twin udm bench-load", "twin sweep"} <= paths
    assert len(LEAVES) >= 17


@pytest.mark.parametrize(("path", "command"), COMMANDS, ids=_ids(COMMANDS))
def test_output_paths_are_dash_o_output(path, command):
    for option in _options(command):
        names = option.opts + option.secondary_opts
        if any(name.startswith("--out") for name in names) or "-o" in names or option.name.startswith("out"):
            assert sorted(names) == ["--output", "-o"], f"{path}: {'/'.join(names)} should be -o/--output"


@pytest.mark.parametrize(("path", "command"), COMMANDS, ids=_ids(COMMANDS))
def test_format_is_a_file_format_and_json_is_a_flag(path, command):
    for option in _options(command):
        if "--format" in option.opts:
            choices = set(getattr(option.type, "choices", ()))
            assert not choices & {"text", "json"}, f"{path}: --format {sorted(choices)}; use --json for JSON"
        if "--json" in option.opts:
            assert option.is_flag, f"{path}: --json must be a flag"


@pytest.mark.parametrize(("path", "command"), LEAVES, ids=_ids(LEAVES))
def test_every_report_has_json(path, command):
    has_json = any("--json" in option.opts for option in _options(command))
    assert has_json != (path in NO_REPORT), (f"{path}: no --json" if not has_json
                                             else f"{path} has --json: take it out of NO_REPORT")


@pytest.mark.parametrize(("path", "command"), COMMANDS, ids=_ids(COMMANDS))
def test_same_word_for_the_same_thing(path, command):
    for option in _options(command):
        names = option.opts + option.secondary_opts
        if "--seed" in names:
            assert isinstance(option.type, (click.types.IntParamType, click.IntRange)), \
                f"{path}: --seed is {option.type.name}, but a seed is always an integer"
        if option.metavar == "BUILD":
            assert path.startswith("twin ") and names == ["--map"], f"{path}: a build folder is --map BUILD"
        if option.metavar == "AREA.geojson":
            assert names == ["--polygon"], f"{path}: an area file is --polygon AREA.geojson"


@pytest.mark.parametrize("root", sorted(GROUPS))
def test_groups_own_verbosity_and_subcommands_do_not_configure_logging(root):
    group = GROUPS[root]
    options = {name: option for option in _options(group) for name in option.opts}
    assert options["-v"] is options["--verbose"] and options["-v"].count
    assert options["-q"] is options["--quiet"] and options["-q"].count
    for path, command in COMMANDS:
        if not path.startswith(f"{root} "):
            continue
        for option in _options(command):
            assert not {"-v", "--verbose", "--log-level"} & set(option.opts), \
                f"{path}: {option.opts} -- verbosity is the group's -v/-q ({root} -v {path.split(' ', 1)[1]} ...)"


@pytest.mark.parametrize(("path", "command"), COMMANDS, ids=_ids(COMMANDS))
def test_help_starts_with_an_example_of_the_command(path, command):
    root, *rest = path.split()
    result = CliRunner().invoke(GROUPS[root], [*rest, "--help"])
    assert result.exit_code == 0, result.output
    text = result.output.split("\n\n", 1)[1]  # after "Usage: ..."
    summary, body = text.split("\n\n", 1)
    assert summary.strip() and not summary.strip().startswith("$"), f"{path}: --help starts with a summary line"
    first = body.strip().splitlines()[0].strip()
    assert first.startswith(f"$ {path} ") or first == f"$ {path}", \
        f"{path}: --help should show an example right after the summary, not {first!r}"


@pytest.mark.parametrize("root", sorted(GROUPS))
def test_verbosity_sets_the_log_level_once_for_every_subcommand(root, tmp_path):
    """`ROOT -v CMD` logs at INFO, `ROOT -vv` at DEBUG, `ROOT -q` only errors: the group sets the level before
    the subcommand runs (here one that stops at once on a missing input). Users type the flags after the
    subcommand too (`mapkit validate -q map.xodr`): the same levels, still set by the group."""
    missing = str(tmp_path / "missing")
    command = ["drive", "--map", missing, "--random"] if root == "twin" else ["info", missing + ".xodr"]
    logger = logging.getLogger()
    before = logger.level
    try:
        for flags, level in ((["-q"], logging.ERROR), ([], logging.WARNING), (["-v"], logging.INFO),
                             (["-vv"], logging.DEBUG), (["-v", "-q"], logging.WARNING)):
            for args in ([*flags, *command], [command[0], *flags, *command[1:]], [*command, *flags]):
                logger.setLevel(logging.CRITICAL)
                result = CliRunner().invoke(GROUPS[root], args)
                assert result.exit_code == 2 and "missing" in result.output, result.output
                assert logger.level == level, (args, logging.getLevelName(logger.level))
        # one -v before the subcommand and one -q after it cancel out
        logger.setLevel(logging.CRITICAL)
        CliRunner().invoke(GROUPS[root], ["-v", *command, "-q"])
        assert logger.level == logging.WARNING
    finally:
        logger.setLevel(before)


def test_old_spellings_still_work_for_one_release_with_one_line_on_stderr(tmp_path):
    from tests.validate_network import write_network

    xodr = str(write_network(tmp_path, "net.xodr"))
    new = CliRunner().invoke(mapkit_cli, ["validate", xodr, "--json"])
    old = CliRunner().invoke(mapkit_cli, ["validate", xodr, "--format", "json"], prog_name="mapkit")
    assert old.exit_code == new.exit_code == 0 and old.stdout == new.stdout and new.stderr == ""
    assert old.stderr == ("mapkit validate: --format json is deprecated, use --json (the old spelling goes in the "
                          "next release)\n")
    text = CliRunner().invoke(mapkit_cli, ["validate", xodr, "--format=text"])
    assert text.stdout == CliRunner().invoke(mapkit_cli, ["validate", xodr]).stdout
    assert "--format text is deprecated, use nothing (the default)" in text.stderr
    # a file format is not an old spelling: --format stays what it is where it names one, and is refused elsewhere
    assert "No such option '--format'" in CliRunner().invoke(mapkit_cli, ["validate", xodr, "--format", "yaml"]).stderr
    served = CliRunner().invoke(twin_cli, ["udm", "serve", "--seed", str(tmp_path / "nope")], prog_name="twin")
    assert served.exit_code == 2
    assert served.stderr.splitlines() == [
        "twin udm serve: --seed is deprecated, use --map (the old spelling goes in the next release)",
        f"Error: {tmp_path / 'nope'}: the --map build folder does not exist"]


def test_verbosity_after_the_subcommand_leaves_its_own_options_and_double_dash_alone():
    from tavf_mapkit.cli.options import verbosity_tokens

    assert verbosity_tokens(["a.xodr", "-vv", "--quiet", "-q", "--json"], own={"--json"}) == (["a.xodr", "--json"], 0)
    assert verbosity_tokens(["-q", "x", "--", "-v"], own={"-q", "--quiet"}) == (["-q", "x", "--", "-v"], 0)
    assert verbosity_tokens(["-qv", "-vx", "-"], own=set()) == (["-qv", "-vx", "-"], 0)
    # build and sweep keep their own -q (no progress lines) and take -v after the command
    build = CliRunner().invoke(mapkit_cli, ["build", "/nonexistent/in.osm", "-q", "-v"])
    assert build.exit_code == 2 and "No such option" not in build.output


def test_respelling_leaves_arguments_after_double_dash_and_option_values_alone():
    from tavf_mapkit.cli.options import FORMAT_TO_JSON, respelled

    renamed = {"--out": "--output", "--format": FORMAT_TO_JSON}
    assert respelled(["--out=a", "--format", "json", "--", "--out"], renamed, "t") == \
        ["--output=a", "--json", "--", "--out"]
    assert respelled(["--outside", "--format"], renamed, "t") == ["--outside", "--format"]
