"""What every command shares: the default paths, the errors a command ends with, the
config file's path."""

from __future__ import annotations

import logging
import signal
import sys
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING

from hermsd.api import client

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


def control_socket(given: Path | None) -> Path:
    """The daemon's socket for a command (`find_socket`); a simulated daemon's, found because
    no service's socket exists, is said on stderr, so no command talks to it unawares."""
    path = client.find_socket(given)
    if given is None and path == client.simulated_socket_path():
        print(
            f"hermsd: using the simulated daemon's socket {path} (there is no "
            f"{client.DEFAULT_SOCKET}; --socket PATH for another)",
            file=sys.stderr,
        )
    return path
