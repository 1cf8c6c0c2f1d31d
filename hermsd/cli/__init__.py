"""The commands: `hermsd` and its subcommands."""

from hermsd.cli.commands import main

__all__ = ["main"]
