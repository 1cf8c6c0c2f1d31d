"""The commands' side of the control socket: one request, one reply, bounded in time."""

from __future__ import annotations

import json
import os
import socket
import tempfile
from pathlib import Path
from typing import Any

from hermsd.api.protocol import MAX_LINE, Request, encode, request_message
from hermsd.config.read import key_range

DEFAULT_SOCKET = Path("/run/hermsd/control.sock")
SOCKET_NAME = "control.sock"
LONGEST_PERIOD = key_range("control.period")[1]  # s: the most control.period may be


def command_timeout(period: float) -> float:
    """How long to wait for a command's reply: it comes after the next period boundary, so
    up to two periods (one under way, one to apply it), and 5 s for a loaded machine."""
    return 2.0 * period + 5.0


TIMEOUT = command_timeout(LONGEST_PERIOD)  # s: long enough whatever the daemon's period
REPLY_LIMIT = 1 << 20  # bytes: a status reply is a few kB


class NoDaemonError(Exception):
    """Nothing answers on the socket: the message names the path and why."""


class ReplyError(Exception):
    """The daemon's answer could not be read."""


def default_socket_path(given: Path | None = None) -> Path:
    """`given`, else systemd's $RUNTIME_DIRECTORY/control.sock, else /run/hermsd/control.sock."""
    if given is not None:
        return given
    runtime = os.environ.get("RUNTIME_DIRECTORY", "").split(":")[0]
    return Path(runtime, SOCKET_NAME) if runtime else DEFAULT_SOCKET


def simulated_socket_path() -> Path:
    """Where `run --simulate` listens, the same for every terminal of one user:
    $XDG_RUNTIME_DIR/hermsd-sim/control.sock, else hermsd-sim-UID/control.sock in the
    temporary directory (/tmp)."""
    runtime = os.environ.get("XDG_RUNTIME_DIR", "")
    if runtime and os.path.isdir(runtime):
        return Path(runtime, "hermsd-sim", SOCKET_NAME)
    return Path(tempfile.gettempdir(), f"hermsd-sim-{os.getuid()}", SOCKET_NAME)


def find_socket(given: Path | None = None) -> Path:
    """The socket a command talks to: `given`, else $RUNTIME_DIRECTORY's, else the service's
    (/run/hermsd/control.sock) when it exists, else a simulated daemon's when it exists, else
    the service's. A service's socket always wins over a simulated one."""
    path = default_socket_path(given)
    if given is not None or path != DEFAULT_SOCKET or os.path.lexists(path):
        return path
    simulated = simulated_socket_path()
    return simulated if os.path.lexists(simulated) else path


def ask(path: Path, request: Request, timeout: float = TIMEOUT) -> dict[str, Any]:
    """Send `request` to the daemon at `path` and return its reply (ok or not)."""
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM | socket.SOCK_CLOEXEC)
    sock.settimeout(timeout)
    with sock:
        try:
            sock.connect(os.fspath(path))
        except (FileNotFoundError, ConnectionRefusedError):
            raise NoDaemonError(f"no hermsd is running: nothing answers on {path}") from None
        except PermissionError:
            raise NoDaemonError(
                f"permission denied on {path} (the socket is for the hermsd group: "
                "`sudo usermod -aG hermsd $USER`, then log in again)"
            ) from None
        except OSError as error:
            raise NoDaemonError(f"cannot reach hermsd on {path}: {error.strerror}") from None
        line = encode(request_message(request))
        assert len(line) <= MAX_LINE
        unsent: OSError | None = None
        try:
            sock.sendall(line)
        except TimeoutError:
            raise ReplyError(
                f"hermsd on {path} did not take the request within {timeout:g} s"
            ) from None
        except OSError as error:  # closed at once (EPIPE): its one line may say why (busy)
            unsent = error
        try:
            reply = _read_line(sock)
        except (OSError, ReplyError) as error:
            if unsent is not None:
                raise ReplyError(
                    f"hermsd on {path} closed the connection before taking the request "
                    f"({unsent.strerror}): nothing was sent, nothing changed"
                ) from None
            if isinstance(error, TimeoutError):
                raise ReplyError(unanswered(timeout)) from None
            if isinstance(error, OSError):
                raise ReplyError(f"the connection to {path} failed: {error.strerror}") from None
            raise
    try:
        message = json.loads(reply)
    except (UnicodeDecodeError, json.JSONDecodeError):
        raise ReplyError(f"hermsd on {path} answered something that is not JSON") from None
    if not isinstance(message, dict) or "ok" not in message:
        raise ReplyError(f"hermsd on {path} answered something that is not a reply")
    return message


def unanswered(timeout: float) -> str:
    """Why a request sent but not answered is not reported as failed: it may have been applied."""
    return (
        f"hermsd did not answer within {timeout:g} s: the outcome is unknown, see the status "
        "(a command may have been applied: send it again only if the status says it was not)"
    )


def _read_line(sock: socket.socket) -> bytes:
    data = bytearray()
    while b"\n" not in data:
        chunk = sock.recv(65536)
        if not chunk:
            raise ReplyError("hermsd closed the connection without an answer")
        data += chunk
        if len(data) > REPLY_LIMIT:
            raise ReplyError("hermsd's answer is longer than any reply should be")
    return bytes(data[: data.index(b"\n")])
