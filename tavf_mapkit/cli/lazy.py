"""A click group that imports subcommand modules only when they are used, and turns our errors into one line."""

from __future__ import annotations

import importlib
import sys

import click

from tavf_mapkit.cli.options import Command, VerbosityAnywhere
from tavf_mapkit.errors import MapkitError


class LazyGroup(VerbosityAnywhere):
    """Subcommands are ``{name: "package.module:attribute"}``; importing them lazily keeps ``--help`` fast."""

    command_class = Command  # ``@group.command(renamed=...)`` understands the spellings of the last release

    def __init__(self, *args, lazy_commands: dict[str, str] | None = None, **kwargs):
        super().__init__(*args, **kwargs)
        self.lazy_commands = dict(lazy_commands or {})

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(set(super().list_commands(ctx)) | set(self.lazy_commands))

    def get_command(self, ctx: click.Context, name: str) -> click.Command | None:
        if name in self.lazy_commands:
            module_name, attribute = self.lazy_commands[name].split(":")
            return getattr(importlib.import_module(module_name), attribute)
        return super().get_command(ctx, name)

    def invoke(self, ctx: click.Context):
        try:
            return super().invoke(ctx)
        except MapkitError as error:
            click.echo(f"Error: {error}", err=True)
            sys.exit(error.exit_code)
        except KeyboardInterrupt:
            click.echo("Interrupted.", err=True)
            sys.exit(130)
