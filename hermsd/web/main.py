"""`hermsd web`: read the config's `web` section, bind, serve until stopped."""

from __future__ import annotations

import asyncio
import getpass
import logging
import socket
import sys
from pathlib import Path

import h11
import uvicorn
from starlette.applications import Starlette
from uvicorn.protocols.http.h11_impl import H11Protocol

from hermsd.config.rules import split_listen
from hermsd.config.schema import Config
from hermsd.web.app import WebSettings, allowed_hosts, create_app
from hermsd.web.passwords import hash_password, parse_hash

log = logging.getLogger("hermsd")

REQUEST_TIMEOUT_S = 5.0  # for a request to arrive whole: a phone sends one in well under 1 s
KEEP_ALIVE_S = 5  # an idle connection kept for the page's next request
MAX_CONNECTIONS = 64  # open at once: the event streams (hub.MAX_PAGES, 32) and requests


class WebSetupError(Exception):
    """The page cannot start as configured; the message says what to change."""


def settings_from(config: Config, socket_path: Path) -> WebSettings:
    web = config.web
    password = None if web.password_hash is None else parse_hash(web.password_hash)
    view = web.read_only_view == "on"
    if password is None and not view:
        raise WebSetupError(
            "the page would show nothing to anyone: set web.password_hash (make one with "
            "`hermsd web --hash-password`), or web.read_only_view: on"
        )
    hosts = allowed_hosts(web.allowed_hosts)
    return WebSettings(socket_path, password, web.session_lifetime * 3600.0, view, hosts=hosts)


def bind(listen: str) -> socket.socket:
    """A listening TCP socket for `listen` (HOST:PORT)."""
    address = split_listen(listen)
    if address is None:
        raise WebSetupError(f"--listen {listen!r}: expected HOST:PORT, e.g. 127.0.0.1:8080")
    try:
        return listening_socket(*address)
    except OSError as error:
        raise WebSetupError(f"cannot listen on {listen}: {error.strerror}") from None


def listening_socket(host: str, port: int) -> socket.socket:
    """A TCP socket listening on `host`:`port` (0: any free port), with TCP_NODELAY.

    TCP_NODELAY, inherited by the accepted connections: uvicorn writes a response's headers
    and body in two sends, and with Nagle's algorithm the body then waits for the client's
    delayed ACK, 40 ms on Linux, on every request (bench/web.py found it)."""
    info = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    family, kind, proto, _name, where = info[0]
    sock = socket.socket(family, kind, proto)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.bind(where)
        sock.listen(128)
    except BaseException:
        sock.close()
        raise
    return sock


class _BoundedH11(H11Protocol):
    """uvicorn's HTTP/1.1 (h11) with the bounds it lacks: a request must arrive whole (its
    headers and body) within `request_timeout` s of the connection opening or of the last
    response, else the connection is closed (uvicorn times out only an idle connection, and
    any byte stops that clock: a half-sent request stayed open for ever); and a connection
    beyond `max_connections` open is closed at once."""

    request_timeout = REQUEST_TIMEOUT_S
    max_connections = MAX_CONNECTIONS
    _deadline: asyncio.TimerHandle | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        super().connection_made(transport)
        if len(self.connections) > self.max_connections:
            transport.close()
            return
        self._await_request()

    def handle_events(self) -> None:
        super().handle_events()
        if self.conn.their_state not in (h11.IDLE, h11.SEND_BODY):  # the request is in
            self._cancel_deadline()

    def on_response_complete(self) -> None:
        super().on_response_complete()
        if not self.transport.is_closing() and self.conn.their_state is h11.IDLE:
            self._await_request()

    def connection_lost(self, exc: Exception | None) -> None:
        self._cancel_deadline()
        super().connection_lost(exc)

    def _await_request(self) -> None:
        self._cancel_deadline()
        self._deadline = self.loop.call_later(self.request_timeout, self._deadline_passed)

    def _cancel_deadline(self) -> None:
        if self._deadline is not None:
            self._deadline.cancel()
            self._deadline = None

    def _deadline_passed(self) -> None:
        self._deadline = None
        if self.conn.their_state in (h11.IDLE, h11.SEND_BODY):
            self.transport.close()


def make_server(
    app: Starlette,
    request_timeout: float = REQUEST_TIMEOUT_S,
    max_connections: int = MAX_CONNECTIONS,
) -> uvicorn.Server:
    """The HTTP server for `app` (uvicorn: HTTP/1.1 by h11, pure Python), bounded as
    `_BoundedH11` says. X-Forwarded-* headers are not taken from anyone (`app.secure_request`
    reads X-Forwarded-Proto itself): any program on this machine could send them."""
    bounds = {"request_timeout": request_timeout, "max_connections": max_connections}
    protocol = type("BoundedH11", (_BoundedH11,), bounds)
    config = uvicorn.Config(
        app,
        log_level="warning",
        access_log=False,
        server_header=False,
        proxy_headers=False,
        timeout_graceful_shutdown=2,
        timeout_keep_alive=KEEP_ALIVE_S,
        http=protocol,
    )
    return uvicorn.Server(config)


def serve(app: Starlette, sock: socket.socket) -> None:
    """Serve `app` on `sock` until SIGTERM or SIGINT (uvicorn's own handlers)."""
    asyncio.run(make_server(app).serve(sockets=[sock]))


def run(config: Config, socket_path: Path, listen: str | None) -> int:
    settings = settings_from(config, socket_path)
    where = listen or config.web.listen
    sock = bind(where)
    log.info(
        "web page on http://%s/ (control socket %s; viewing %s)",
        where,
        socket_path,
        "open" if settings.read_only_view else "after login",
    )
    with sock:
        serve(create_app(settings), sock)
    return 0


def ask_new_password() -> str:
    """The password to hash: typed twice on a terminal, else one line of stdin."""
    if sys.stdin.isatty():
        first = getpass.getpass("new password for the web page: ")
        if getpass.getpass("again: ") != first:
            raise WebSetupError("the two passwords differ")
    else:
        first = sys.stdin.readline().rstrip("\n")
    if len(first) < 8:
        raise WebSetupError("the password is shorter than 8 characters")
    return first


def print_hash() -> int:
    print(hash_password(ask_new_password()))
    return 0
