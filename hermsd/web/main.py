"""`hermsd web`: read the config's `web` section, bind, serve until stopped."""

from __future__ import annotations

import asyncio
import getpass
import logging
import socket
import sys
from pathlib import Path

import uvicorn
from starlette.applications import Starlette

from hermsd.config.rules import split_listen
from hermsd.config.schema import Config
from hermsd.web.app import WebSettings, allowed_hosts, create_app
from hermsd.web.passwords import hash_password, parse_hash

log = logging.getLogger("hermsd")


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


def make_server(app: Starlette) -> uvicorn.Server:
    """The HTTP server for `app` (uvicorn: HTTP/1.1 by h11, pure Python)."""
    config = uvicorn.Config(
        app,
        log_level="warning",
        access_log=False,
        server_header=False,
        proxy_headers=True,  # X-Forwarded-* from 127.0.0.1 only (a reverse proxy there)
        timeout_graceful_shutdown=2,
        http="h11",
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
