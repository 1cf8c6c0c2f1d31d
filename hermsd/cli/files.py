"""The commands on a brewer's files: check-config, program import and check, forget-model."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from hermsd.cli.common import (
    UserError,
)
from hermsd.cli.logs import _write_new
from hermsd.cli.run import (
    _default_state_directory,
    _latch_file_refused,
)
from hermsd.config import read
from hermsd.config import schema as config_module
from hermsd.config.schema import ConfigError
from hermsd.control.learning import ModelStore
from hermsd.safety.latches import LatchStore, StateError

if TYPE_CHECKING:
    pass


def cmd_program_import(args: argparse.Namespace) -> int:
    """Write the program of a BeerXML recipe's mash; an existing file is never replaced."""
    from hermsd.program import beerxml

    try:
        text = beerxml.to_yaml(beerxml.read(args.file, args.recipe))
    except beerxml.BeerXMLError as error:
        raise UserError(str(error)) from None
    if args.output is None:
        sys.stdout.write(text)
        return 0
    _write_new(args.output, lambda temporary: temporary.write_text(text, encoding="utf-8"))
    return 0


def cmd_forget_model(args: argparse.Namespace) -> int:
    """Delete the learned model; the daemon uses the config's prior from its next start."""
    directory: Path = args.state or _default_state_directory()
    store = ModelStore(directory)
    try:
        forgotten = store.forget()
    except OSError as error:
        # Only a refused permission is the user's to fix by who runs it; a state path that is
        # not a directory is the option's (or the config's) to fix.
        fix = (
            "run as root or as the user hermsd runs as"
            if isinstance(error, PermissionError)
            else f"is {directory} the state directory? --state names it"
        )
        raise UserError(f"{store.path}: {error.strerror or error} ({fix})") from None
    if forgotten:
        print(f"forgot {store.path}: hermsd starts from the config's model at its next start")
    else:
        print(f"nothing learned in {directory}")
    return 0


def cmd_check_config(args: argparse.Namespace) -> int:
    """The file as hermsd will use it, and the safety limits it puts in force; for `run` on
    hardware unless --simulate is given.

    `output.backend: sim` is valid only in a simulated run, so it is refused here by
    default: a file checked for the service must not fail when the service starts.
    """
    from hermsd.runtime.build import model_in_force, safety_limits, stored_model
    from hermsd.safety.limits import format_limits

    document = read.load_document(args.file)
    if document.config.output.backend == "sim" and not args.simulate:
        line, column = document.written["output.backend"]
        raise ConfigError(
            [
                config_module.Problem(
                    os.fspath(args.file),
                    line,
                    column,
                    "output.backend",
                    "'sim' is the simulated tun's output, which `hermsd run` uses only with "
                    "--simulate (choose serial-rts, serial-dtr or gpio for the tun, or check "
                    "a file for simulation with check-config --simulate)",
                )
            ]
        )
    if args.state:
        try:
            LatchStore(args.state).load()  # as `run` reads it at its start
        except StateError as error:
            raise _latch_file_refused(error) from None
    shown = read.on_simulated_tun(document.config) if args.simulate else document.config
    print(read.dump_yaml(shown), end="")
    # As YAML comments, so that the output still reads back as the config it is.
    stored, problem = (
        stored_model(ModelStore(args.state), document.config) if args.state else (None, None)
    )
    if problem is not None:
        print(f"\n# learned model ignored: {problem}")
    choice = model_in_force(stored, document.config)
    source = (
        "nothing measured yet" if choice.measured is None else f"the tun as {choice.describe()}"
    )
    print(f"\n# safety limits in force ({source}):")
    limits = safety_limits(document.config, choice.measured)
    for row in format_limits(limits, document.config.control.setpoint):
        print(f"#   {row}")
    return 0
