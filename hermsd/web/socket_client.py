"""The web server's side of the control socket: one request, one reply, without blocking.

The same protocol as `hermsd.api.client`, on asyncio streams, so that a command waiting
for the daemon's next period boundary holds up no other page. Requests are plain JSON
objects: the page's program commands (`program`, `confirm`) pass through unchanged, and a
daemon that does not know one refuses it with its own message.
"""

from __future__ import annotations

import asyncio
import json
import os
from pathlib import Path
from typing import Any

from hermsd.api.client import REPLY_LIMIT, TIMEOUT, unanswered
from hermsd.api.protocol import MAX_LINE, VERSION, encode


class DaemonUnavailable(Exception):
    """The daemon cannot be asked (not running, no permission, no answer): the message says
    which, for the page."""


class OutcomeUnknown(DaemonUnavailable):
    """The request was sent and not answered in time: the daemon may have applied it."""


async def ask(path: Path, message: dict[str, Any], timeout: float = TIMEOUT) -> dict[str, Any]:
    """Send one request (`v` added) and return the daemon's reply, ok or not."""
    line = encode({"v": VERSION, **message})
    if len(line) > MAX_LINE:
        raise DaemonUnavailable(f"the request is longer than {MAX_LINE} bytes")
    sent = False
    try:
        async with asyncio.timeout(timeout):
            reader, writer = await asyncio.open_unix_connection(os.fspath(path), limit=REPLY_LIMIT)
            try:
                writer.write(line)
                await writer.drain()
                sent = True
                reply = await reader.readline()
            finally:
                writer.close()
    except TimeoutError:
        if sent:
            raise OutcomeUnknown(unanswered(timeout)) from None
        raise DaemonUnavailable(f"hermsd did not take the request within {timeout:g} s") from None
    except (FileNotFoundError, ConnectionRefusedError):
        raise DaemonUnavailable(f"no hermsd is running: nothing answers on {path}") from None
    except PermissionError:
        raise DaemonUnavailable(
            f"permission denied on {path} (this user must be in the hermsd group)"
        ) from None
    except (OSError, ValueError) as error:  # ValueError: a reply over REPLY_LIMIT
        raise DaemonUnavailable(f"the connection to hermsd failed: {error}") from None
    try:
        answer = json.loads(reply)
    except (UnicodeDecodeError, json.JSONDecodeError):
        raise DaemonUnavailable("hermsd answered something that is not JSON") from None
    if not isinstance(answer, dict) or "ok" not in answer:
        raise DaemonUnavailable("hermsd answered something that is not a reply")
    return answer
