"""`--help` of every subcommand, enumerated from the parser: a help text argparse cannot
format (a bare % in it) is a traceback for the brewer who asks for help."""

from __future__ import annotations

import argparse

import pytest

from hermsd.cli import commands as cli


def _commands(
    parser: argparse.ArgumentParser | None = None, path: tuple[str, ...] = ()
) -> list[tuple[str, ...]]:
    """Every subcommand's words, nested ones too."""
    found: list[tuple[str, ...]] = []
    for action in (parser or cli._parser())._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, child in sorted(action.choices.items()):
                found += [(*path, name), *_commands(child, (*path, name))]
    return found


def test_there_are_subcommands_to_check() -> None:
    assert {("run",), ("set",), ("simulate",), ("replay",)} <= set(_commands())


@pytest.mark.parametrize("command", _commands(), ids=" ".join)
def test_every_subcommand_prints_its_help(
    command: tuple[str, ...], capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as stopped:
        cli.main([*command, "--help"])
    out, err = capsys.readouterr()
    assert stopped.value.code == 0, err
    assert out.startswith("usage: hermsd " + " ".join(command))
