"""What every command shares: the default paths, the errors a command ends with, the
config file's path."""

from __future__ import annotations

import logging
import signal
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    pass


DEFAULT_CONFIG = Path("/etc/hermsd/hermsd.yaml")


DEFAULT_STATE = Path("/var/lib/hermsd")


EXIT_USAGE = 2


log = logging.getLogger("hermsd")


class UserError(Exception):
    """A problem the user can fix; printed as one line, exit code 2."""


class Unreachable(Exception):
    """No daemon answers on the control socket, or it is too busy to take the connection;
    printed as one line, exit code 1."""


class Shutdown(BaseException):
    """SIGTERM or SIGINT: unwinds the loop from wherever it is, so the heater goes off now."""


def _on_signal(signum: int, frame: FrameType | None) -> None:
    raise Shutdown(signal.Signals(signum).name)


def config_path(path: Path | None, *, simulate: bool) -> Path | None:
    """The config file to use; None means the built-in defaults (simulating without one)."""
    if path is None:
        if simulate and not DEFAULT_CONFIG.exists():
            return None
        path = DEFAULT_CONFIG
    if not path.exists():
        raise UserError(f"no config file at {path} (copy config/hermsd.yaml there, or --config)")
    return path
