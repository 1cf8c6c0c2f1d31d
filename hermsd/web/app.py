"""The web page's HTTP side (Starlette): the page, its data, logins, and changes.

Routes:
    GET  /                 the page (static files under /static/, shipped in the package)
    GET  /api/session      whether this browser is logged in, its CSRF token, what it may do
    POST /api/login        {"password": "..."}: a session cookie (rate-limited, see auth.py)
    POST /api/logout
    GET  /api/history      the last 24 h as columns (t, pv, setpoint, output), the clock and
                           the setpoint's band (±°C, drawn about its line)
    GET  /api/events       server-sent events: the status of each new period
    POST /api/command      one change, forwarded to the daemon's control socket:
                           {"cmd": "set", "setpoint": 72}, {"cmd": "set", "mode": "manual",
                           "output": 40}, {"cmd": "set", "mode": "auto"},
                           {"cmd": "reset-alarm", "kinds": [the alarms shown]},
                           {"cmd": "confirm", "step": 0},
                           {"cmd": "program", "action": "next"|"pause"|"resume"|"stop"}
                           ("step", optional with confirm and next: the index of the
                           step shown, refused by the daemon once another is current);
                           a reset's reply has "reset": what it cleared, what stands, why
    POST /api/program/import  {"data": "<a BeerXML file, base64>" | "xml": "<pasted XML>",
                           "filename": "recipe.xml", "recipe": "Weizen" | null}: the
                           program file `hermsd program import` writes of it, checked as
                           it checks it ({"yaml", "name", "steps"}; a refusal in one line);
                           nothing is sent to the daemon
    POST /api/program      {"yaml": "<a program file>", "filename": "mash.yaml",
                           "ready_by": "06:30" | null}: the file read and checked here
                           (hermsd.program.model, every problem as FILE:LINE:COL in
                           "problems", nothing sent), then started through the socket

Every request must name this machine in its Host header (`host_allowed`): a page elsewhere
that makes its own name resolve to the Pi (DNS rebinding) is refused, so it cannot read the
tun through a visitor's browser even with `web.read_only_view` on. Every POST needs a JSON
body (a form from another site cannot send one without the browser asking this server
first, which it refuses), an Origin, if sent, naming this host,
and, but for the login, the session's CSRF token in X-CSRF-Token. Seeing the tun needs a
login unless `web.read_only_view` is on. A change the daemon refuses is answered 422 with
its one-line reason; the daemon changed nothing.
"""

from __future__ import annotations

import asyncio
import base64
import binascii
import contextlib
import ipaddress
import json
import logging
import socket
import time
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

from starlette.applications import Starlette
from starlette.concurrency import run_in_threadpool
from starlette.middleware import Middleware
from starlette.middleware.gzip import GZipMiddleware
from starlette.requests import ClientDisconnect, Request
from starlette.responses import JSONResponse, PlainTextResponse, Response, StreamingResponse
from starlette.routing import Route
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from hermsd.api import jsontext
from hermsd.api.client import LONGEST_PERIOD, command_timeout
from hermsd.api.jsontext import JsonTextError
from hermsd.api.protocol import (
    History,
    ProgramStart,
    ProtocolError,
    Status,
    parse_request,
    request_message,
)
from hermsd.program import beerxml
from hermsd.program.model import READY_BY, ProgramError, parse
from hermsd.web.auth import LoginLimiter, Session, Sessions, csrf_matches
from hermsd.web.hub import Hub, TooManyPages, page_status
from hermsd.web.passwords import PasswordHash, verify_password
from hermsd.web.socket_client import DaemonUnavailable, OutcomeUnknown, ask

log = logging.getLogger("hermsd")

COOKIE = "hermsd_session"
MAX_BODY = 4096  # bytes of a POST body: a command is under 100
MAX_PROGRAM_BODY = 1 << 16  # of a program's POST: a program file with comments; the socket's
# start request (hermsd.api.protocol.MAX_LINE) holds the longest program
MAX_RECIPE_BODY = 1 << 19  # of a BeerXML import's POST: one recipe exported by brewing
# software, with its hops, notes and base64's third more
MAX_FILENAME = 100
KEEPALIVE_S = 15.0  # a comment line on an idle event stream, so proxies keep it open
PROGRAM_ACTIONS = ("next", "pause", "resume", "stop")
STATIC = {
    "app.js": "text/javascript; charset=utf-8",
    "app.css": "text/css; charset=utf-8",
    "uPlot.iife.min.js": "text/javascript; charset=utf-8",
    "uPlot.min.css": "text/css; charset=utf-8",
    "uPlot.LICENSE": "text/plain; charset=utf-8",
}
SECURITY_HEADERS = [
    (
        b"content-security-policy",
        b"default-src 'self'; style-src 'self' 'unsafe-inline'; img-src 'self' data:; "
        b"frame-ancestors 'none'; form-action 'self'; base-uri 'none'",
    ),
    (b"x-content-type-options", b"nosniff"),
    (b"referrer-policy", b"no-referrer"),
    (b"x-frame-options", b"DENY"),
    (b"cache-control", b"no-store"),
]


@dataclass(frozen=True, slots=True)
class WebSettings:
    socket: Path
    password: PasswordHash | None  # None: nobody can log in, nothing can be changed
    session_lifetime: float  # s without use
    read_only_view: bool  # whether seeing the tun needs no login
    poll: float | None = None  # s between status polls; None: from the control period
    hosts: tuple[str, ...] = ("localhost",)  # names the page answers to (`allowed_hosts`)
    stale_after: float | None = None  # s a reading stays live; None: two control periods


class BadInput(ValueError):
    """A request the page should not have sent; the message says what is wrong."""


class _SecurityHeaders:
    """Adds SECURITY_HEADERS to every response (plain ASGI: streams stay streams)."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return

        async def send_with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                message["headers"] = [*message.get("headers", []), *SECURITY_HEADERS]
            await send(message)

        await self.app(scope, receive, send_with_headers)


def allowed_hosts(listed: tuple[str, ...] | None) -> tuple[str, ...]:
    """The host names the page answers to: `web.allowed_hosts`, else this machine's own
    (localhost, its hostname, any mDNS name: a phone opens http://raspberrypi.local:8080)."""
    if listed is not None:
        return listed
    return ("localhost", socket.gethostname(), "*.local")


def host_allowed(header: str | None, names: tuple[str, ...]) -> bool:
    """Whether a Host header names this machine: an IP address (never a rebinding page's own
    name), or one of `names` ("*.example.org": any name under it); any port."""
    host = (header or "").strip().lower()
    if host.startswith("["):  # an IPv6 address: [::1]:8080
        address, _, rest = host[1:].partition("]")
        return _is_port(rest) and _is_address(address)
    name, colon, port = host.partition(":")
    name = name.rstrip(".")
    if not name or not _is_port(colon + port):
        return False
    if _is_address(name):
        return True
    for allowed in (n.lower().rstrip(".") for n in names):
        if name == allowed or (allowed.startswith("*.") and name.endswith(allowed[1:])):
            return True
    return False


def _is_port(text: str) -> bool:
    """Whether `text` is what may follow a host: nothing, or ':' and a port number."""
    return not text or (text[0] == ":" and text[1:].isdigit())


def _is_address(text: str) -> bool:
    try:
        ipaddress.ip_address(text)
    except ValueError:
        return False
    return True


class _Unexpected:
    """Answers an exception no handler took with a one-line 500 and logs it here, once per
    request: Starlette's own handler would re-raise it for uvicorn to log a second time, and
    no traceback reaches the client. A handler's kind of failure (exception type and path)
    is logged with its traceback the first time, in one line after that, so a request that
    can be repeated cannot fill the journal with tracebacks."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app
        self._seen: set[tuple[str, str]] = set()

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        started = False

        async def noting_start(message: Message) -> None:
            nonlocal started
            started = started or message["type"] == "http.response.start"
            await send(message)

        try:
            await self.app(scope, receive, noting_start)
        except ClientDisconnect:  # it went (or was cut off at the request deadline)
            return
        except Exception as error:
            kind = (type(error).__name__, str(scope.get("path", "")))
            said = f"web: {scope.get('method')} {kind[1]} failed: {error!r}"
            if kind in self._seen:
                log.error("%s (again)", said)
            else:
                self._seen.add(kind)
                log.exception("%s", said)
            if not started:  # else the client sees the response cut short
                answer = _error(500, f"the server failed on this request ({kind[0]}): see its log")
                await answer(scope, receive, send)


class _KnownHosts:
    """Refuses (400, one line) a request whose Host header is not `host_allowed`."""

    def __init__(self, app: ASGIApp, names: tuple[str, ...]) -> None:
        self.app = app
        self.names = names

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] in ("http", "websocket"):
            host = dict(scope["headers"]).get(b"host", b"").decode("latin-1")
            if not host_allowed(host, self.names):
                refusal = PlainTextResponse(
                    f"this page does not answer to the host name {host!r}: open it by the "
                    "Pi's address, or add the name to web.allowed_hosts\n",
                    status_code=400,
                )
                await refusal(scope, receive, send)
                return
        await self.app(scope, receive, send)


def create_app(settings: WebSettings, clock: Callable[[], float] = time.monotonic) -> Starlette:
    """The web application, polling the daemon at `settings.socket` while it runs."""
    hub = Hub(settings.socket, settings.poll, clock=clock, stale_after=settings.stale_after)
    sessions = Sessions(settings.session_lifetime)
    limiter = LoginLimiter()
    static = {
        name: (resources.files("hermsd.web").joinpath("static", name).read_bytes(), kind)
        for name, kind in STATIC.items()
    }
    page = resources.files("hermsd.web").joinpath("static", "index.html").read_bytes()

    def session_of(request: Request) -> tuple[str | None, Session | None]:
        sid = request.cookies.get(COOKIE)
        return sid, sessions.find(sid, clock())

    def may_view(request: Request) -> bool:
        return settings.read_only_view or session_of(request)[1] is not None

    async def index(request: Request) -> Response:
        return Response(page, media_type="text/html; charset=utf-8")

    async def static_file(request: Request) -> Response:
        name = request.path_params["name"]
        if name not in static:
            return Response("not found", status_code=404, media_type="text/plain")
        body, kind = static[name]
        response = Response(body, media_type=kind)
        response.headers["cache-control"] = "public, max-age=3600"
        return response

    async def session_info(request: Request) -> Response:
        _sid, session = session_of(request)
        return _json(_session_body(session))

    def _session_body(session: Session | None) -> dict[str, Any]:
        return {
            "logged_in": session is not None,
            "csrf": None if session is None else session.csrf,
            "can_log_in": settings.password is not None,
            "view_open": settings.read_only_view,
        }

    async def login(request: Request) -> Response:
        data = await _json_body(request)
        if settings.password is None:
            return _error(403, "no password is set: the page only shows (web.password_hash)")
        password = data.get("password")
        if not isinstance(password, str) or not 0 < len(password) <= 1024:
            return _error(400, "password: expected text of 1 to 1024 characters")
        client = client_address(request)
        wait = limiter.attempt(client, clock())
        if wait > 0:
            response = _error(429, f"too many login attempts: try again in {wait:.0f} s")
            response.headers["retry-after"] = str(max(1, round(wait)))
            return response
        stored = settings.password
        if not await run_in_threadpool(verify_password, password, stored):
            return _error(401, "wrong password")
        limiter.succeeded(client, clock())
        old, _ = session_of(request)
        sessions.end(old)
        sid, session = sessions.create(clock())
        response = _json(_session_body(session))
        response.set_cookie(  # no max-age: the server ends it after the lifetime without use
            COOKIE,
            sid,
            httponly=True,
            samesite="strict",
            secure=secure_request(request),
            path="/",
        )
        return response

    async def logout(request: Request) -> Response:
        await _json_body(request)
        sid, session = session_of(request)
        if session is None or not csrf_matches(session, request.headers.get("x-csrf-token")):
            return _error(403, "not logged in")
        sessions.end(sid)
        response = _json(_session_body(None))
        response.delete_cookie(COOKIE, path="/", httponly=True, samesite="strict")
        return response

    async def history(request: Request) -> Response:
        if not may_view(request):
            return _error(401, "log in to see the tun")
        plain, gzipped = hub.history_body()
        if "gzip" not in request.headers.get("accept-encoding", ""):
            return Response(plain, media_type="application/json")
        response = Response(gzipped, media_type="application/json")
        response.headers["content-encoding"] = "gzip"  # the middleware leaves it be
        response.headers["vary"] = "Accept-Encoding"
        return response

    async def events(request: Request) -> Response:
        if not may_view(request):
            return _error(401, "log in to see the tun")
        since_text = request.query_params.get("since")
        try:
            since = None if since_text is None else float(since_text)
        except ValueError:
            return _error(400, f"since: expected a number, got {since_text!r}")
        try:
            queue = hub.open_page(since)
        except TooManyPages as error:
            return _error(503, str(error))
        sid = request.cookies.get(COOKIE)

        def still_allowed() -> bool:
            return settings.read_only_view or sessions.alive(sid, clock())

        return StreamingResponse(
            _stream(hub, queue, still_allowed),
            media_type="text/event-stream",
            headers={"x-accel-buffering": "no"},
        )

    def refused(request: Request) -> Response | None:
        """Why this browser may not change anything now; None: it may."""
        _sid, session = session_of(request)
        if session is None:
            return _error(401, "log in to change anything")
        if not csrf_matches(session, request.headers.get("x-csrf-token")):
            return _error(403, "the page's security token is missing or old: reload the page")
        return None

    async def command(request: Request) -> Response:
        data = await _json_body(request)
        return refused(request) or await forward(command_message(data))

    async def program_start(request: Request) -> Response:
        data = await _json_body(request, MAX_PROGRAM_BODY)
        if (answer := refused(request)) is not None:
            return answer
        try:
            message = await run_in_threadpool(program_message, data)  # up to 64 kB of YAML
        except ProgramError as error:
            body = {"ok": False, "error": "the program has errors: nothing was sent"}
            return _json({**body, "problems": str(error).splitlines()}, 400)
        return await forward(message)

    async def program_import(request: Request) -> Response:
        data = await _json_body(request, MAX_RECIPE_BODY)
        if (answer := refused(request)) is not None:
            return answer
        try:
            imported = await run_in_threadpool(imported_program, data)  # parsed off the loop
        except beerxml.BeerXMLError as error:
            return _error(400, str(error))
        return _json({"ok": True, **imported})

    async def forward(message: dict[str, Any]) -> Response:
        """The daemon's answer to one change: its status, or its reason for refusing."""
        period = LONGEST_PERIOD if hub.period is None else hub.period
        try:
            reply = await ask(settings.socket, message, command_timeout(period))
        except OutcomeUnknown as error:
            return _error(504, str(error))
        except DaemonUnavailable as error:
            return _error(503, str(error))
        if not reply["ok"]:
            return _error(422, str(reply.get("error", "refused")))
        hub.poke()
        # A reset's reply says what it cleared and what stands: the page says it, not "done".
        reset = {"reset": reply["reset"]} if "reset" in reply else {}
        return _json({"ok": True, "status": page_status(reply), **reset})

    async def bad_input(request: Request, error: Exception) -> Response:
        return _error(400, str(error))

    @contextlib.asynccontextmanager
    async def lifespan(app: Starlette) -> AsyncIterator[None]:
        task = asyncio.create_task(hub.run())
        try:
            yield
        finally:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task

    app = Starlette(
        routes=[
            Route("/", index),
            Route("/static/{name}", static_file),
            Route("/favicon.ico", lambda request: Response(status_code=204)),
            Route("/api/session", session_info),
            Route("/api/login", login, methods=["POST"]),
            Route("/api/logout", logout, methods=["POST"]),
            Route("/api/history", history),
            Route("/api/events", events),
            Route("/api/command", command, methods=["POST"]),
            Route("/api/program", program_start, methods=["POST"]),
            Route("/api/program/import", program_import, methods=["POST"]),
        ],
        middleware=[
            Middleware(_SecurityHeaders),
            Middleware(_Unexpected),
            Middleware(_KnownHosts, names=settings.hosts),
            Middleware(GZipMiddleware, minimum_size=1000),
        ],
        exception_handlers={BadInput: bad_input},
        lifespan=lifespan,
    )
    app.state.hub = hub
    return app


def client_address(request: Request) -> str:
    """Who tries a login, for its rate limit: the address the connection comes from, never
    X-Forwarded-For, which any program on this machine could set anew for each try (and so
    escape its own limit and spend everyone's). Behind the reverse proxy every browser is the
    proxy's one client (docs/web.md)."""
    return request.client.host if request.client else "unknown"


def secure_request(request: Request) -> bool:
    """Whether the browser reached the page over TLS: directly, or through a reverse proxy on
    this machine that says so in X-Forwarded-Proto (one that lies gains a stricter cookie)."""
    if request.url.scheme == "https":
        return True
    forwarded = request.headers.get("x-forwarded-proto", "").strip().lower() == "https"
    return forwarded and _is_loopback(client_address(request))


def _is_loopback(text: str) -> bool:
    try:
        return ipaddress.ip_address(text).is_loopback
    except ValueError:
        return False


def command_message(data: dict[str, Any]) -> dict[str, Any]:
    """The socket request for one change from the page; BadInput for anything else.

    Each is read by the protocol's own parser (so the same rules, and messages, as for
    `hermsd set`), but for a program's start, which has its own address; the daemon checks
    whether the program's commands apply."""
    command = data.get("cmd")
    if command == "program" and data.get("action") not in PROGRAM_ACTIONS:
        raise BadInput(f"program: action must be one of {', '.join(PROGRAM_ACTIONS)}")
    try:
        request = parse_request(json.dumps({**data, "v": 1}).encode())
    except ProtocolError as error:
        raise BadInput(str(error)) from None
    if isinstance(request, Status | History):
        raise BadInput(f"{command} changes nothing: not a command for this address")
    message = request_message(request)
    del message["v"]
    return message


def program_message(data: dict[str, Any]) -> dict[str, Any]:
    """The socket's `program start` request for a program file sent by the page: BadInput
    for a malformed request, ProgramError (every problem, FILE:LINE:COL) for a bad file."""
    unknown = set(data) - {"yaml", "filename", "ready_by"}
    if unknown:
        raise BadInput(f"program: unknown field(s) {', '.join(sorted(unknown))}")
    text, filename = data.get("yaml"), _filename(data, "program.yaml")
    if not isinstance(text, str) or not text.strip():
        raise BadInput("program: choose a program file or paste its YAML")
    ready_by = data.get("ready_by") or None
    if ready_by is not None and not (isinstance(ready_by, str) and READY_BY.fullmatch(ready_by)):
        raise BadInput(f"ready by: {ready_by!r} is not a local time (HH:MM, e.g. 06:30)")
    message = request_message(ProgramStart(parse(text, filename), ready_by))
    del message["v"]
    return message


def imported_program(data: dict[str, Any]) -> dict[str, Any]:
    """The program file of a BeerXML recipe sent by the page, read and checked by `hermsd
    program import`'s own code: BadInput for a malformed request, BeerXMLError (one line,
    FILE:LINE: what) for a recipe that makes no program."""
    unknown = set(data) - {"data", "xml", "filename", "recipe"}
    if unknown:
        raise BadInput(f"import: unknown field(s) {', '.join(sorted(unknown))}")
    filename = _filename(data, "recipe.xml")
    encoded, pasted = data.get("data"), data.get("xml")
    xml: bytes | str
    if isinstance(encoded, str) and encoded:  # a file's bytes: its own declared encoding
        try:
            xml = base64.b64decode(encoded, validate=True)
        except binascii.Error:
            raise BadInput("data: expected the file's bytes in base64") from None
    elif isinstance(pasted, str) and pasted.strip():
        xml = pasted  # text: decoded already, whatever encoding its declaration names
    else:
        raise BadInput("import: choose a BeerXML file or paste its XML")
    recipe = data.get("recipe") or None
    if recipe is not None and not (isinstance(recipe, str) and len(recipe) <= MAX_FILENAME):
        raise BadInput(f"recipe: expected a recipe's name of at most {MAX_FILENAME} characters")
    program = beerxml.program_of(xml, filename, recipe, choose="the Recipe field")
    return {"yaml": beerxml.to_yaml(program), "name": program.name, "steps": len(program.steps)}


def _filename(data: dict[str, Any], default: str) -> str:
    """The name of the file the page sent (its problems are said by it); BadInput if odd."""
    filename = data.get("filename") or default
    if not isinstance(filename, str) or len(filename) > MAX_FILENAME or "/" in filename:
        raise BadInput(f"filename: expected a file name of at most {MAX_FILENAME} characters")
    return filename


async def _json_body(request: Request, limit: int = MAX_BODY) -> dict[str, Any]:
    """The POST body as a JSON object; BadInput if it is not one, or is from another site."""
    kind = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if kind != "application/json":
        raise BadInput("expected a JSON body (Content-Type: application/json)")
    origin = request.headers.get("origin")
    if origin is not None and origin.split("://", 1)[-1] != request.headers.get("host"):
        raise BadInput("a change must come from this page (the Origin is another site)")
    body = bytearray()
    async for chunk in request.stream():
        body += chunk
        if len(body) > limit:
            raise BadInput(f"the request is longer than {limit} bytes")
    try:
        data = jsontext.loads(bytes(body), limit)
    except JsonTextError as error:
        raise BadInput(f"the request is not acceptable JSON: {error}") from None
    if not isinstance(data, dict):
        raise BadInput("expected a JSON object")
    return data


async def _stream(
    hub: Hub, queue: asyncio.Queue[bytes | None], allowed: Callable[[], bool]
) -> AsyncIterator[bytes]:
    """The page's events, ended (nothing more sent) once its login is over: checked before
    each event and keepalive, so within KEEPALIVE_S of a logout or expiry."""
    try:
        while True:
            try:
                event = await asyncio.wait_for(queue.get(), KEEPALIVE_S)
            except TimeoutError:
                event = b": keepalive\n\n"
            if event is None or not allowed():
                return
            yield event
    finally:
        hub.close_page(queue)


def _json(body: dict[str, Any], status: int = 200) -> JSONResponse:
    return JSONResponse(body, status_code=status)


def _error(status: int, message: str) -> JSONResponse:
    return _json({"ok": False, "error": message}, status)
