"""The daemon's side of the control socket: a thread that serves clients beside the loop.

Why a thread, not the loop polling a non-blocking socket: `status` must stay cheap at a
thousand requests a second, and the loop's period is seconds long. Served from the loop, a
request would wait up to a period, or the loop would do unbounded work at each boundary;
either delays an SSR edge or starves the clients. Here the loop thread never touches a
socket or JSON: at each period boundary it publishes a snapshot of immutable references
(`Snapshot`, a few µs) and takes at most COMMANDS_PER_PERIOD validated commands from a
bounded queue (`take`); the server thread answers `status` from the latest snapshot and
replies to a command once the loop has applied it (`LoopLink` in `link.py`).

The GIL: while this thread runs Python the loop thread, even at SCHED_FIFO, waits for the
interpreter lock when it wakes. Every burst of work here is short and bounded (at most
MAX_LINE bytes read per client per wake-up, a status reply encoded once per snapshot and
then reused) and each burst ends in a system call that releases the lock (select, recv,
send), so the loop waits for at most one burst, tens of µs, not the interpreter's 5 ms
switch interval. bench/socket_load.py measures the loop's lateness under 1,000 requests/s.

Clients are bounded too: at most MAX_CLIENTS connections, PER_PROCESS of them from one
client process and PER_USER from one user's processes (told by SO_PEERCRED), so that one
client holding connections open cannot shut out `hermsd status`, the web page or the MQTT
bridge; a connection beyond a bound is told "busy: …" in one line and closed. A client idle
for IDLE_TIMEOUT s is closed, and a reply that cannot be sent within SEND_TIMEOUT s (a client
that stopped reading) ends its connection. An unexpected exception while serving one client
is logged in one line, answered with an error and ends that connection alone: the thread
serves on.

A client process (told by its pid, whatever connections it opens) may send REQUEST_BURST
requests other than `status` and `history` at once, then REQUEST_RATE a second
(`RequestLimit`): each is parsed here, a program start checked (up to 64 KiB, milliseconds of
Python), and one after another they would keep the loop waiting for the interpreter lock at
its wake-ups. Beyond that its requests are refused, unread, with one line saying when to try
again.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import math
import os
import selectors
import socket
import stat
import struct
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hermsd.api.protocol import (
    BUSY,
    MAX_LINE,
    STARTING,
    Command,
    History,
    ProtocolError,
    Status,
    encode,
    error_reply,
    parse_request,
)

log = logging.getLogger("hermsd")

MAX_CLIENTS = 32
PER_PROCESS = 8  # connections one client process may hold: the web bridge's poll and commands
PER_USER = 16  # … one user's processes: the other users (each bridge runs as its own) keep half
IDLE_TIMEOUT = 60.0  # s without a request: the connection is closed
SEND_TIMEOUT = 5.0  # s a reply may wait for a client to read
COMMANDS_PER_PERIOD = 8  # commands the loop applies at one boundary; the rest wait for the next
SOCKET_MODE = 0o660
REQUEST_RATE = 2.0  # requests a second a client process may send beyond status and history
REQUEST_BURST = 10  # … and at once: a brewer's taps, a bridge's command and its retry
SMALL_REQUEST = 256  # bytes: a status or history request is shorter; over the limit, a
# longer line is refused unread (a program is kilobytes), a shorter one read to tell


class SocketInUseError(OSError):
    """Another daemon answers on the socket path, or the path is not a socket."""


@dataclass(slots=True)
class Pending:
    """A command on its way to the loop; `reply` is set by the loop once it has applied it."""

    command: Command
    reply: dict[str, Any] | None = None


class RequestLimit:
    """A token bucket per client process for the requests that cost the server thread work
    (all but `status` and `history`): `burst` at once, then `rate` a second. Time is given."""

    def __init__(self, rate: float = REQUEST_RATE, burst: int = REQUEST_BURST) -> None:
        self.rate, self.burst = rate, burst
        self._buckets: dict[int, tuple[float, float]] = {}  # pid: (tokens, when counted)

    def wait(self, pid: int, now: float) -> float:
        """Seconds until `pid` may send a request that costs (0: it may now)."""
        return max(0.0, (1.0 - self._tokens(pid, now)) / self.rate)

    def charge(self, pid: int, now: float) -> None:
        """`pid` sent a request that costs."""
        self._buckets[pid] = (self._tokens(pid, now) - 1.0, now)

    def forget_full(self, now: float) -> None:
        """Drop the buckets that have filled up again: they are as if never used."""
        full = [pid for pid in self._buckets if self._tokens(pid, now) >= self.burst]
        for pid in full:
            del self._buckets[pid]

    def _tokens(self, pid: int, now: float) -> float:
        tokens, then = self._buckets.get(pid, (float(self.burst), now))
        return min(float(self.burst), tokens + (now - then) * self.rate)


@dataclass(slots=True)
class _Client:
    sock: socket.socket
    pid: int  # the client's process: what the request limit counts by
    uid: int  # the client's user
    last_active: float
    inbox: bytearray = field(default_factory=bytearray)
    outbox: bytearray = field(default_factory=bytearray)
    waiting: Pending | None = None  # a command the loop has not answered yet
    closing: bool = False  # end the connection once the outbox is sent
    draining: bool = False  # our side ended: what the client still sends is discarded
    send_since: float | None = None


StatusReply = Callable[[], bytes]
"""The status reply line, encoded (once per control period, by `LoopLink.status_line`)."""

HistoryReply = Callable[[History], bytes]
"""A page of the history, encoded (`LoopLink.history_line`: joins rows encoded by the loop)."""

Arrival = Callable[[Command], Command]
"""A command as it arrives, made definite (`LoopLink.arrived`: the step a confirm is for)."""


def _as_sent(command: Command) -> Command:
    return command


def _no_history(request: History) -> bytes:
    return encode(error_reply("this daemon keeps no history"))


def _starting() -> bytes:
    return encode(error_reply(STARTING))


class ControlServer:
    """Serves the socket at `path` on its own thread; `status` builds the status reply,
    `history` a page of the history."""

    def __init__(
        self,
        path: Path,
        status: StatusReply = _starting,
        history: HistoryReply = _no_history,
        *,
        clock: Callable[[], float] = time.monotonic,
        limit: RequestLimit | None = None,
    ) -> None:
        self.path = path
        self._clock = clock
        self._limit = limit or RequestLimit()
        self._status = status
        self._history = history
        self._arrived: Arrival = _as_sent
        self._commands: deque[Pending] = deque()
        self._selector = selectors.DefaultSelector()
        self._listener: socket.socket | None = None
        self._wake_read, self._wake_write = os.pipe2(os.O_NONBLOCK | os.O_CLOEXEC)
        self._stop = False
        self._thread: threading.Thread | None = None
        self._clients: dict[int, _Client] = {}

    # -- the daemon's side ----------------------------------------------------------------

    def bind(self) -> socket.socket:
        """Take the socket path (mode 0660) without serving yet; SocketInUseError if another
        daemon answers there. `hermsd run` binds before it opens any output, so that a second
        daemon on the tun is refused before it can touch the heater's lines."""
        if self._listener is None:
            self._listener = _bind(self.path)
        return self._listener

    def answer_with(
        self, status: StatusReply, history: HistoryReply, arrived: Arrival = _as_sent
    ) -> None:
        """What `status` and `history` are answered from, and what a command is as it
        arrives (before `start`)."""
        self._status, self._history, self._arrived = status, history, arrived

    def start(self) -> None:
        """Bind the socket if `bind` has not, and start serving."""
        self._selector.register(self.bind(), selectors.EVENT_READ)
        self._selector.register(self._wake_read, selectors.EVENT_READ)
        self._thread = threading.Thread(target=self._serve, name="hermsd-control", daemon=True)
        self._thread.start()

    def close(self) -> None:
        """Stop serving and remove the socket file (pending commands are not applied)."""
        self._stop = True
        self.wake()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        for client in list(self._clients.values()):
            self._drop(client)
        if self._listener is not None:
            self._listener.close()
            with contextlib.suppress(FileNotFoundError):
                self.path.unlink()
        self._selector.close()
        os.close(self._wake_read)
        os.close(self._wake_write)

    def take(self, limit: int = COMMANDS_PER_PERIOD) -> list[Pending]:
        """On the loop: up to `limit` commands, oldest first (deque pops are atomic)."""
        taken: list[Pending] = []
        while self._commands and len(taken) < limit:
            taken.append(self._commands.popleft())
        return taken

    def wake(self) -> None:
        """On the loop: tell the server thread replies are ready (never blocks)."""
        with contextlib.suppress(BlockingIOError):
            os.write(self._wake_write, b"\0")

    # -- the server thread ----------------------------------------------------------------

    def _serve(self) -> None:
        try:
            while not self._stop:
                for key, events in self._selector.select(timeout=1.0):
                    if key.fileobj is self._listener:
                        self._accept()
                    elif key.fileobj == self._wake_read:
                        with contextlib.suppress(BlockingIOError):
                            os.read(self._wake_read, 4096)
                    else:
                        client = self._clients.get(key.fd)
                        if client is not None:
                            self._guarded(client, self._service, events)
                for client in list(self._clients.values()):
                    self._guarded(client, self._collect_reply)
                self._expire(self._clock())
        except Exception:  # beyond any one client (the selector): the loop runs on without
            log.exception("control socket stopped")

    def _guarded(self, client: _Client, serve: Callable[..., None], *args: int) -> None:
        """`serve(client, *args)`; an exception it raises ends that client's connection alone,
        said in one line to the journal and to the client."""
        try:
            serve(client, *args)
        except Exception as error:
            self._failed(client, error)

    def _failed(self, client: _Client, error: Exception) -> None:
        what = f"{type(error).__name__}: {' '.join(str(error).split())}"
        log.error(
            "control socket: serving pid %d failed (%s); its connection is closed, the socket "
            "serves on",
            client.pid,
            what,
        )
        applied = "; the command may have been applied: see the status"
        outcome = "" if client.waiting is None else applied
        client.waiting = None
        client.inbox.clear()
        client.closing = True
        try:
            self._send(client, error_reply(f"hermsd failed to answer ({what}){outcome}"))
        except Exception:  # the reply cannot be made or sent either: just close
            self._drop(client)

    def _accept(self) -> None:
        assert self._listener is not None
        try:
            sock, _ = self._listener.accept()
        except (BlockingIOError, InterruptedError):
            return
        sock.setblocking(False)
        pid, uid = _peer(sock)
        busy = self._busy(pid, uid)
        if busy is not None:
            self._reap_hung_up()
            busy = self._busy(pid, uid)
        if busy is not None:
            with contextlib.suppress(OSError):
                sock.send(encode(error_reply(f"{BUSY}{busy}")))
            sock.close()
            return
        client = _Client(sock, pid, uid, self._clock())
        self._clients[sock.fileno()] = client
        self._selector.register(sock, selectors.EVENT_READ)

    def _busy(self, pid: int, uid: int) -> str | None:
        """Why a new connection from `pid` of `uid` is refused (None: it is taken in)."""
        of_process = sum(1 for client in self._clients.values() if client.pid == pid)
        if of_process >= PER_PROCESS:
            return (
                f"this process (pid {pid}) holds {of_process} connections already, the most one "
                "process may (close one: each request needs one only until its reply)"
            )
        of_user = sum(1 for client in self._clients.values() if client.uid == uid)
        if of_user >= PER_USER:
            return (
                f"the processes of uid {uid} hold {of_user} connections already, the most one "
                "user's may (close some)"
            )
        if len(self._clients) >= MAX_CLIENTS:
            return f"{MAX_CLIENTS} clients connected already (try again in a minute)"
        return None

    def _reap_hung_up(self) -> None:
        """Drop clients that have hung up but whose end-of-file is not read yet (a burst of
        short connections while this thread was not running), so they hold no place."""
        for client in list(self._clients.values()):
            try:
                hung_up = client.sock.recv(1, socket.MSG_PEEK) == b""
            except (BlockingIOError, InterruptedError):
                continue
            except OSError:
                hung_up = True
            if hung_up:
                self._drop(client)

    def _service(self, client: _Client, events: int) -> None:
        if events & selectors.EVENT_WRITE:
            self._flush(client)
        if events & selectors.EVENT_READ and client.sock.fileno() >= 0:
            self._read(client)

    def _read(self, client: _Client) -> None:
        try:
            data = client.sock.recv(MAX_LINE)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            self._drop(client)
            return
        if not data:
            self._drop(client)
            return
        if client.draining:
            return
        client.last_active = self._clock()
        client.inbox += data
        if len(client.inbox) > 2 * MAX_LINE:  # requests piling up unanswered: not the protocol
            client.inbox.clear()
            client.closing = True
            self._send(client, error_reply("one request at a time: read each reply first"))
            return
        self._next_request(client)

    def _refuse(self, client: _Client, wait: float) -> None:
        """One line for a client over its request limit; the rest of what it sent unread."""
        client.inbox.clear()
        client.closing = True
        limit = self._limit
        self._send(
            client,
            error_reply(
                f"refused: this client (pid {client.pid}) sent more than {limit.burst} "
                f"requests at once or {limit.rate:g} a second (status and history aside); "
                f"try again in {math.ceil(wait * 10.0) / 10.0:.1f} s"
            ),
        )

    def _next_request(self, client: _Client) -> None:
        """Answer the next complete line, if the client is not waiting for the loop."""
        if client.waiting is not None or client.closing:
            return
        now = self._clock()
        wait = self._limit.wait(client.pid, now)
        end = client.inbox.find(b"\n")
        if wait > 0.0 and (end > SMALL_REQUEST or (end < 0 and len(client.inbox) > SMALL_REQUEST)):
            self._refuse(client, wait)  # a costly request from a client over its limit: unread
            return
        if (end < 0 and len(client.inbox) >= MAX_LINE) or end + 1 > MAX_LINE:
            client.closing = True  # the rest of the line cannot be told from the next request
            self._send(client, error_reply(f"request longer than {MAX_LINE} bytes"))
            return
        if end < 0:
            return
        line = bytes(client.inbox[:end])
        del client.inbox[: end + 1]
        try:
            request = parse_request(line)
        except ProtocolError as error:
            if wait > 0.0:
                self._refuse(client, wait)
                return
            self._limit.charge(client.pid, now)
            self._send(client, error_reply(str(error)))
            return
        if wait > 0.0 and not isinstance(request, Status | History):
            self._refuse(client, wait)  # status and history are answered whatever the rate
            return
        if not isinstance(request, Status | History):
            self._limit.charge(client.pid, now)
        if isinstance(request, Status):
            client.outbox += self._status()
            self._flush(client)
        elif isinstance(request, History):
            client.outbox += self._history(request)
            self._flush(client)
        else:  # one command a client at a time: the queue is never longer than MAX_CLIENTS
            client.waiting = Pending(self._arrived(request))
            self._commands.append(client.waiting)

    def _collect_reply(self, client: _Client) -> None:
        pending = client.waiting
        if pending is not None and pending.reply is not None:
            self._send(client, pending.reply)
            client.waiting = None
        if client.waiting is None and b"\n" in client.inbox:
            self._next_request(client)

    def _send(self, client: _Client, message: dict[str, Any]) -> None:
        client.outbox += encode(message)
        self._flush(client)

    def _flush(self, client: _Client) -> None:
        if client.outbox:
            try:
                sent = client.sock.send(client.outbox)
            except (BlockingIOError, InterruptedError):
                sent = 0
            except OSError:
                self._drop(client)
                return
            del client.outbox[:sent]
        if client.outbox:
            if client.send_since is None:
                client.send_since = self._clock()
                self._selector.modify(client.sock, selectors.EVENT_READ | selectors.EVENT_WRITE)
            return
        if client.send_since is not None:
            client.send_since = None
            self._selector.modify(client.sock, selectors.EVENT_READ)
        if client.closing and not client.draining:
            # Closing with the rest of an over-long line unread would reset the connection
            # and lose the reply: end our side, and discard what still comes until EOF.
            client.draining = True
            with contextlib.suppress(OSError):
                client.sock.shutdown(socket.SHUT_WR)

    def _expire(self, now: float) -> None:
        for client in list(self._clients.values()):
            stuck = client.send_since is not None and now - client.send_since > SEND_TIMEOUT
            limit = SEND_TIMEOUT if client.draining else IDLE_TIMEOUT
            idle = client.waiting is None and now - client.last_active > limit
            if stuck or idle:
                self._drop(client)
        self._limit.forget_full(now)

    def _drop(self, client: _Client) -> None:
        fd = client.sock.fileno()
        if fd < 0:
            return
        self._clients.pop(fd, None)
        with contextlib.suppress(KeyError, ValueError):
            self._selector.unregister(client.sock)
        client.sock.close()


def _peer(sock: socket.socket) -> tuple[int, int]:
    """The pid and uid of the process at the other end ((0, -1) when the kernel cannot say)."""
    size = struct.calcsize("3i")
    try:
        pid, uid, _gid = struct.unpack(
            "3i", sock.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, size)
        )
    except OSError:
        return 0, -1
    return int(pid), int(uid)


def _bind(path: Path) -> socket.socket:
    """A listening socket at `path`, mode 0660; a stale one left by a crash is replaced."""
    _remove_stale(path)
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM | socket.SOCK_CLOEXEC)
    try:
        sock.bind(os.fspath(path))  # mode 0777 & ~umask: not group-writable until the chmod
        os.chmod(path, SOCKET_MODE)
        sock.listen(MAX_CLIENTS)
        sock.setblocking(False)
    except BaseException:
        sock.close()
        raise
    return sock


def _remove_stale(path: Path) -> None:
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return
    if not stat.S_ISSOCK(mode):
        raise SocketInUseError(errno.EEXIST, f"{path} exists and is not a socket (remove it)")
    probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    probe.settimeout(1.0)
    try:
        probe.connect(os.fspath(path))
        holder, _uid = _peer(probe)
    except (ConnectionRefusedError, FileNotFoundError):
        path.unlink(missing_ok=True)  # nothing listens: left by a daemon that died
        return
    finally:
        probe.close()
    who = f"another hermsd (pid {holder})" if holder else "another hermsd"
    raise SocketInUseError(errno.EADDRINUSE, f"{who} answers on {path}")
