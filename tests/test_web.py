"""`hermsd web` over HTTP against a simulated daemon: logins, sessions, CSRF, the login rate
limits, bad input, the read-only view, a program's start; and the password hash and the `web`
config section."""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import re
import socket
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from test_reload import BASE, edited
from webpage import PASSWORD, PERIOD, STORED, TIMEOUT, Site, served, site

import hermsd.web
from hermsd.api.client import LONGEST_PERIOD as TIMEOUT_LONGEST_PERIOD
from hermsd.api.client import TIMEOUT as TIMEOUT_LONGEST
from hermsd.api.client import unanswered
from hermsd.api.jsontext import MAX_DEPTH
from hermsd.cli import main
from hermsd.config import read as config_read
from hermsd.config.rules import split_listen
from hermsd.config.schema import ConfigError
from hermsd.web.app import WebSettings, command_message, create_app, host_allowed
from hermsd.web.auth import (
    GLOBAL_BURST,
    GLOBAL_REFILL_S,
    LOGIN_BURST,
    LOGIN_REFILL_S,
    LoginLimiter,
    Sessions,
)
from hermsd.web.hub import PAGE_DERIVED, PAGE_FIELDS, Hub
from hermsd.web.main import WebSetupError, listening_socket, settings_from
from hermsd.web.passwords import PasswordHash, hash_password, parse_hash, verify_password
from hermsd.web.socket_client import DaemonUnavailable, OutcomeUnknown, ask


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Site]:
    with site(tmp_path_factory.mktemp("web")) as served:
        yield served


def _client(live: Site) -> httpx.Client:
    return httpx.Client(base_url=live.url, timeout=TIMEOUT)


LoggedIn = tuple[httpx.Client, str]


@pytest.fixture
def logged_in(live: Site) -> Iterator[LoggedIn]:
    """A client with a session, and the session's CSRF token."""
    with _client(live) as client:
        reply = client.post("/api/login", json={"password": PASSWORD})
        assert reply.status_code == 200
        yield client, reply.json()["csrf"]


def test_a_login_gives_a_strict_http_only_session_cookie_and_a_csrf_token(live: Site) -> None:
    with _client(live) as client:
        reply = client.post("/api/login", json={"password": PASSWORD})
    assert reply.status_code == 200
    cookie = reply.headers["set-cookie"]
    attributes = {part.strip().split("=")[0].lower() for part in cookie.split(";")}
    assert cookie.startswith("hermsd_session=")
    assert {"httponly", "samesite", "path"} <= attributes and "samesite=strict" in cookie.lower()
    # No fixed expiry: the server ends a session after web.session_lifetime without use.
    assert "max-age" not in attributes and "expires" not in attributes
    session = cookie.split(";")[0].split("=", 1)[1]
    assert len(session) >= 43  # 32 random bytes, base64
    body = reply.json()
    assert body["logged_in"] and len(body["csrf"]) >= 43 and body["csrf"] != session


def test_a_change_is_applied_with_login_and_token(live: Site, logged_in: LoggedIn) -> None:
    client, token = logged_in
    reply = client.post(
        "/api/command", json={"cmd": "set", "setpoint": 70.5}, headers={"x-csrf-token": token}
    )
    assert reply.status_code == 200
    assert reply.json()["status"]["setpoint"] == 70.5 == live.daemon.setpoint


@pytest.mark.parametrize(
    ("headers", "status", "says"),
    [
        ({}, 403, "security token is missing or old"),
        ({"x-csrf-token": "forged"}, 403, "security token is missing or old"),
        ({"origin": "http://evil.example"}, 400, "the Origin is another site"),
    ],
)
def test_a_change_without_the_pages_token_changes_nothing(
    live: Site, logged_in: LoggedIn, headers: dict[str, str], status: int, says: str
) -> None:
    client, token = logged_in
    before = live.daemon.setpoint
    if "origin" in headers:
        headers = {**headers, "x-csrf-token": token}
    reply = client.post(
        "/api/command", json={"cmd": "set", "setpoint": before + 1}, headers=headers
    )
    assert reply.status_code == status and says in reply.json()["error"]
    assert live.daemon.setpoint == before


def test_each_period_is_pushed_with_what_the_page_shows_only(live: Site) -> None:
    events: list[dict[str, object]] = []
    with _client(live) as client, client.stream("GET", "/api/events") as stream:
        assert stream.headers["content-type"].startswith("text/event-stream")
        for line in stream.iter_lines():
            if line.startswith("data: "):
                events.append(json.loads(line[len("data: ") :]))
            if len(events) == 3:
                break
    first, *pushed = events
    for event in pushed:  # the limits, model and learned texts were sent too: 2 kB a period
        status = event["status"]
        assert isinstance(status, dict) and set(status) == {*PAGE_FIELDS, *PAGE_DERIVED}
        assert event["rows"] and event["rows"][-1][0] == status["t"]  # type: ignore[index]
    assert pushed[1]["status"]["t"] > first["status"]["t"]  # type: ignore[index]


def test_every_status_field_the_page_script_reads_is_pushed_to_it() -> None:
    """The browser tests hand the page whole statuses; the hub sends it PAGE_FIELDS only, so a
    field the script reads and the hub leaves out would never show on a real page."""
    script = (Path(hermsd.web.__file__).parent / "static" / "app.js").read_text("utf-8")
    read = set(re.findall(r"\bstatus\.([a-z_0-9]+)", script))
    assert {"output2", "alarm_reasons", "warnings", "program"} <= read  # the pattern finds them
    assert read <= {*PAGE_FIELDS, *PAGE_DERIVED}


def test_a_period_reaches_the_page_before_the_next_one_runs(live: Site) -> None:
    with (
        _client(live) as client,
        client.stream("GET", "/api/events") as stream,
        live.held() as last,
    ):
        lines = stream.iter_lines()
        times = (json.loads(line[6:])["status"]["t"] for line in lines if line[:6] == "data: ")
        while next(times) < last:  # the events of the periods before the hold
            pass
        live.step()  # one period, then the loop is held again: no later one runs
        assert next(times) == last + 5.0


def test_manual_mode_with_an_output_and_back_to_auto(live: Site, logged_in: LoggedIn) -> None:
    client, token = logged_in
    headers = {"x-csrf-token": token}
    manual = client.post(
        "/api/command", json={"cmd": "set", "mode": "manual", "output": 40}, headers=headers
    )
    assert manual.status_code == 200
    assert (live.daemon.mode, live.daemon.manual_output) == ("manual", 40.0)
    assert manual.json()["status"]["manual_output"] == 40.0
    auto = client.post("/api/command", json={"cmd": "set", "mode": "auto"}, headers=headers)
    assert auto.status_code == 200 and live.daemon.mode == "auto"


def test_a_form_post_from_another_site_is_refused(logged_in: LoggedIn) -> None:
    client, token = logged_in
    reply = client.post(
        "/api/command",
        content=b"cmd=set&setpoint=90",
        headers={"content-type": "application/x-www-form-urlencoded", "x-csrf-token": token},
    )
    assert reply.status_code == 400 and "expected a JSON body" in reply.json()["error"]


@pytest.mark.parametrize(
    ("command", "status", "says"),
    [
        ({"cmd": "set", "setpoint": "hot"}, 400, 'setpoint: expected a number, got "hot"'),
        ({"cmd": "set", "mode": "boil"}, 422, "control.mode"),
        ({"cmd": "set", "setpoint": 99.5}, 422, "refused, nothing changed"),
        ({"cmd": "status"}, 400, "changes nothing"),
        ({"cmd": "program", "action": "explode"}, 400, "action must be one of next, pause"),
        ({"cmd": "rm -rf"}, 400, "unknown command"),
    ],
)
def test_bad_input_gets_a_clear_message_and_changes_nothing(
    live: Site, logged_in: LoggedIn, command: dict[str, object], status: int, says: str
) -> None:
    client, token = logged_in
    before = (live.daemon.setpoint, live.daemon.mode)
    reply = client.post("/api/command", json=command, headers={"x-csrf-token": token})
    assert reply.status_code == status, reply.text
    assert says in reply.json()["error"] and "\n" not in reply.json()["error"]
    assert (live.daemon.setpoint, live.daemon.mode) == before


def test_an_over_long_request_is_refused(logged_in: LoggedIn) -> None:
    client, token = logged_in
    reply = client.post(
        "/api/command",
        content=json.dumps({"cmd": "set", "pad": "x" * 5000}).encode(),
        headers={"content-type": "application/json", "x-csrf-token": token},
    )
    assert reply.status_code == 400 and "longer than 4096 bytes" in reply.json()["error"]


def test_after_five_wrong_passwords_a_client_waits_even_with_the_right_one(
    tmp_path: Path,
) -> None:
    with site(tmp_path) as fresh, _client(fresh) as client:
        wrong = [client.post("/api/login", json={"password": f"guess{i}"}) for i in range(5)]
        blocked = client.post("/api/login", json={"password": PASSWORD})
    assert [reply.status_code for reply in wrong] == [401] * 5
    # The five took a few seconds of the 60 s it takes to earn one attempt back.
    assert blocked.status_code == 429 and 50 <= int(blocked.headers["retry-after"]) <= 60
    assert "too many login attempts" in blocked.json()["error"]


def test_logins_are_limited_for_all_clients_together() -> None:
    limiter = LoginLimiter()
    waits = [limiter.attempt(f"10.0.0.{i}", 100.0) for i in range(GLOBAL_BURST + 1)]
    assert waits[:GLOBAL_BURST] == [0.0] * GLOBAL_BURST
    assert waits[-1] == pytest.approx(GLOBAL_REFILL_S)  # one attempt back per refill
    assert limiter.attempt("10.0.1.1", 100.0 + GLOBAL_REFILL_S) == 0.0


def test_right_passwords_do_not_count_against_a_client() -> None:
    limiter = LoginLimiter()
    for _ in range(LOGIN_BURST * 3):
        assert limiter.attempt("10.0.0.1", 100.0) == 0.0
        limiter.succeeded("10.0.0.1", 100.0)
    for _ in range(LOGIN_BURST):
        assert limiter.attempt("10.0.0.1", 100.0) == 0.0  # wrong ones
    assert limiter.attempt("10.0.0.1", 100.0) == pytest.approx(LOGIN_REFILL_S)


def test_a_session_ends_after_its_lifetime_without_use() -> None:
    sessions = Sessions(lifetime=600.0)
    sid, session = sessions.create(0.0)
    assert sessions.find(sid, 599.0) is session  # used: the lifetime starts again
    assert sessions.find(sid, 1198.0) is session
    assert sessions.find(sid, 1798.5) is None
    assert sessions.find(sid, 1799.0) is None  # gone for good


def test_without_the_read_only_view_seeing_needs_a_login(tmp_path: Path) -> None:
    with site(tmp_path, read_only_view=False) as closed, _client(closed) as client:
        refused = [client.get(path) for path in ("/api/history", "/api/events")]
        page = client.get("/")
        client.post("/api/login", json={"password": PASSWORD})
        history = client.get("/api/history")
    assert [reply.status_code for reply in refused] == [401, 401]
    assert page.status_code == 200  # the page itself, with its login form
    assert "default-src 'self'" in page.headers["content-security-policy"]
    assert history.status_code == 200 and len(history.json()["t"]) >= 1


def test_the_program_commands_go_to_the_daemon_as_the_socket_protocol_says() -> None:
    assert command_message({"cmd": "program", "action": "pause"}) == {
        "cmd": "program",
        "action": "pause",
    }
    assert command_message({"cmd": "confirm"}) == {"cmd": "confirm"}
    assert command_message({"cmd": "set", "mode": "manual", "output": 40}) == {
        "cmd": "set",
        "mode": "manual",
        "output": 40.0,
    }


# -- the password and the config ------------------------------------------------------------


def test_the_hash_is_scrypt_as_rfc_7914_defines_it() -> None:
    # RFC 7914 §12, second vector: scrypt("password", "NaCl", N=1024, r=8, p=16, 64 bytes).
    digest = bytes.fromhex(
        "fdbabe1c9d3472007856e7190d01e9fe7c6ad7cbc8237830e77376634b373162"
        "2eaf30d92e22a3886ff109279d9830dac727afb94a83ee6d8360cbdfa2cc0640"
    )
    stored = PasswordHash(1024, 8, 16, b"NaCl", digest)
    assert verify_password("password", stored)
    assert not verify_password("Password", stored)


def test_a_made_hash_verifies_only_its_password() -> None:
    stored = parse_hash(hash_password("correct horse"))
    assert stored is not None and len(stored.salt) == 16
    assert verify_password("correct horse", stored) and not verify_password("correct hors", stored)
    assert hash_password("x" * 8) != hash_password("x" * 8)  # a fresh salt each time


@pytest.mark.parametrize(
    "text",
    ["brewing", "scrypt$1000$8$1$AAAAAAAAAAAAAAAAAAAAAA$" + "A" * 43, "scrypt$16384$8$1$short$x"],
)
def test_what_is_not_a_hash_is_refused(text: str) -> None:
    assert parse_hash(text) is None  # 1000 is not a power of two


@pytest.mark.parametrize(
    ("text", "address"),
    [
        ("127.0.0.1:8080", ("127.0.0.1", 8080)),
        ("0.0.0.0:80", ("0.0.0.0", 80)),
        ("[::1]:8443", ("::1", 8443)),
        ("pi.local:8080", ("pi.local", 8080)),
        ("127.0.0.1", None),
        ("127.0.0.1:0", None),
        ("127.0.0.1:65536", None),
        (":8080", None),
    ],
)
def test_listen_is_host_and_port(text: str, address: tuple[str, int] | None) -> None:
    assert split_listen(text) == address


def test_the_web_section_is_checked_like_the_rest_of_the_file() -> None:
    text = edited(
        BASE,
        web__listen='"everywhere"',
        web__password_hash='"hunter2"',
        web__allowed_hosts='["raspberrypi.local:8080"]',
    )
    with pytest.raises(ConfigError) as caught:
        config_read.parse(text, "hermsd.yaml")
    message = str(caught.value)
    assert "web.listen: 'everywhere' is not HOST:PORT" in message
    assert "web.password_hash: not a password hash (expected scrypt$16384$8$1$" in message
    assert (
        "web.allowed_hosts: 'raspberrypi.local:8080' is not a host name (a name alone, no "
        "scheme or port: e.g. brew.example.org, or *.example.org for every name under it; IP "
        "addresses need no entry)"
    ) in message


def test_responses_are_not_held_back_by_nagles_algorithm() -> None:
    # Headers and body go in two sends; with Nagle's algorithm the body waited for the
    # client's delayed ACK, 40 ms a request.
    with listening_socket("127.0.0.1", 0) as listener:
        assert listener.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY) == 1
        with socket.create_connection(listener.getsockname()):
            accepted, _ = listener.accept()
            with accepted:
                assert accepted.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY) == 1


def test_a_page_that_would_show_nothing_to_anyone_does_not_start(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(WebSetupError, match="would show nothing to anyone"):
        settings_from(config_read.parse(BASE), tmp_path / "control.sock")
    path = tmp_path / "hermsd.yaml"
    path.write_text(BASE, encoding="utf-8")
    assert main(["web", "--config", str(path)]) == 2
    error = capsys.readouterr().err
    assert error.startswith("hermsd: the page would show nothing") and "Traceback" not in error


def test_without_a_daemon_the_page_is_told_why(tmp_path: Path) -> None:
    hub = Hub(tmp_path / "control.sock", poll=0.01)

    async def events() -> list[object]:
        queue = hub.open_page(None)
        await hub.refresh()
        return [json.loads((await queue.get() or b"")[len(b"data: ") :]) for _ in range(2)]

    no_reading = {"age": None, "stale_after": 2 * TIMEOUT_LONGEST_PERIOD}  # no period known
    assert asyncio.run(events()) == [
        {"error": "connecting to hermsd", **no_reading},
        {"error": f"no hermsd is running: nothing answers on {hub.socket}", **no_reading},
    ]


def test_hash_password_prints_a_hash_the_config_takes(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    import io

    monkeypatch.setattr("sys.stdin", io.StringIO("a long enough password\n"))
    assert main(["web", "--hash-password"]) == 0
    printed = capsys.readouterr().out.strip()
    stored = parse_hash(printed)
    assert stored is not None and verify_password("a long enough password", stored)
    config_read.parse(edited(BASE, web__password_hash=f'"{printed}"'))


PROGRAM_FILE = "name: Step mash\nsteps:\n  - {name: Rest, setpoint: 66, hold: 60m}\n"


@pytest.mark.parametrize(
    ("body", "says", "problems"),
    [
        (  # a step's hold misspelt (so missing), a setpoint above 100 °C: all, where they are
            {
                "yaml": "steps:\n  - name: Rest\n    setpoint: 166\n    hodl: 60m\n",
                "filename": "mash.yaml",
            },
            "the program has errors: nothing was sent",
            [
                "mash.yaml:2:5: steps[0].hold: missing",
                "mash.yaml:3:15: steps[0].setpoint: 166 °C is out of range",
                "mash.yaml:4:5: steps[0].hodl: unknown key (did you mean 'hold'?)",
            ],
        ),
        ({"yaml": "steps: [\n", "filename": "cut.yaml"}, "nothing was sent", ["cut.yaml:"]),
        ({"yaml": "  "}, "choose a program file or paste its YAML", None),
        ({"yaml": PROGRAM_FILE, "ready_by": "25:00"}, "'25:00' is not a local time", None),
        ({"yaml": PROGRAM_FILE, "filename": "../x.yaml"}, "filename: expected a file", None),
        ({"yaml": PROGRAM_FILE, "run": True}, "unknown field(s) run", None),
        ({"yaml": "x" * 70000}, "longer than 65536 bytes", None),
    ],
)
def test_a_bad_program_is_shown_where_it_is_wrong_and_nothing_is_sent(
    live: Site,
    logged_in: LoggedIn,
    body: dict[str, object],
    says: str,
    problems: list[str] | None,
) -> None:
    client, token = logged_in
    reply = client.post("/api/program", json=body, headers={"x-csrf-token": token})
    assert reply.status_code == 400 and says in reply.json()["error"]
    if problems is not None:
        shown = reply.json()["problems"]
        assert len(shown) == len(problems)
        assert all(line.startswith(start) for line, start in zip(shown, problems, strict=True))
    assert not live.daemon.program.active


def test_a_program_starts_only_with_login_and_token_and_can_be_stopped(
    live: Site, logged_in: LoggedIn
) -> None:
    client, token = logged_in
    body = {"yaml": PROGRAM_FILE, "filename": "step.yaml", "ready_by": "06:30"}
    with _client(live) as stranger:
        assert stranger.post("/api/program", json=body).status_code == 401
    assert client.post("/api/program", json=body).status_code == 403  # no CSRF token
    assert not live.daemon.program.active
    headers = {"x-csrf-token": token}
    try:
        reply = client.post("/api/program", json=body, headers=headers)
        assert reply.status_code == 200, reply.text
        program = reply.json()["status"]["program"]
        assert (program["name"], program["steps"]) == ("Step mash", 1)
        assert program["state"] == "scheduled" and program["starts_at"] is not None
    finally:
        stop = {"cmd": "program", "action": "stop"}
        assert client.post("/api/command", json=stop, headers=headers).status_code == 200
    assert not live.daemon.program.active


# -- a command the daemon does not answer in time --------------------------------------------


def test_a_command_sent_and_not_answered_in_time_is_said_unknown_not_failed(
    tmp_path: Path,
) -> None:
    async def unanswered() -> str:
        async def take(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            await reader.readline()  # taken, and never answered (a period boundary far off)
            await asyncio.sleep(TIMEOUT)
            writer.close()

        server = await asyncio.start_unix_server(take, path=tmp_path / "control.sock")
        async with server:
            with pytest.raises(OutcomeUnknown) as caught:
                await ask(tmp_path / "control.sock", {"cmd": "confirm"}, timeout=0.05)
        return str(caught.value)

    said = asyncio.run(unanswered())
    assert "outcome is unknown, see the status" in said


def test_the_page_waits_two_periods_for_a_command_and_says_504_when_unsure(
    live: Site, logged_in: LoggedIn, monkeypatch: pytest.MonkeyPatch
) -> None:
    waited: list[float] = []

    async def no_answer(path: Path, message: dict[str, object], timeout: float) -> None:
        waited.append(timeout)
        raise OutcomeUnknown(unanswered(timeout))

    monkeypatch.setattr("hermsd.web.app.ask", no_answer)
    client, token = logged_in
    reply = client.post(
        "/api/command", json={"cmd": "program", "action": "next"}, headers={"x-csrf-token": token}
    )
    assert waited == [2 * PERIOD + 5]  # the next boundary, after the one under way, and slack
    assert reply.status_code == 504 and "outcome is unknown" in reply.json()["error"]


def test_without_a_known_period_a_command_waits_for_the_longest_one() -> None:
    assert TIMEOUT_LONGEST == 2 * 60 + 5  # control.period is at most 60 s


# -- the event stream and the poll, past the unexpected ---------------------------------------


def test_a_logout_ends_the_pages_event_stream(tmp_path: Path) -> None:
    with site(tmp_path, read_only_view=False) as closed, _client(closed) as client:
        token = client.post("/api/login", json={"password": PASSWORD}).json()["csrf"]
        with client.stream("GET", "/api/events") as stream:
            lines = stream.iter_lines()
            while not next(lines).startswith("data: "):
                pass
            with closed.held() as last_before, _client(closed) as other:
                other.cookies = client.cookies
                assert other.post(
                    "/api/logout", json={}, headers={"x-csrf-token": token}
                ).is_success
            seen_after = []
            for line in lines:  # a period every 0.05 s: never ends if the stream goes on
                if line.startswith("data: "):
                    seen_after.append(json.loads(line[len("data: ") :])["status"]["t"])
                    assert len(seen_after) < 100
    # the stream ended, and no period run after the logout reached the page
    assert all(t <= last_before for t in seen_after)


def test_an_expired_login_is_not_alive_and_watching_does_not_renew_it() -> None:
    sessions = Sessions(lifetime=60.0)
    sid, _session = sessions.create(now=0.0)
    assert sessions.alive(sid, 60.0) and sessions.alive(sid, 60.0)
    assert not sessions.alive(sid, 60.5)  # alive() counted no use at 60 s
    assert not sessions.alive("forged", 1.0) and not sessions.alive(None, 1.0)


def test_a_reply_the_hub_cannot_read_is_logged_and_the_polling_goes_on(
    live: Site, caplog: pytest.LogCaptureFixture
) -> None:
    """Said once by the hub that cannot read it, while the live page's hub, in the same
    process, polls its daemon on meanwhile: what one hub is given to ask with is its own."""

    async def polled_on() -> int:
        asked: list[dict[str, object]] = []
        third = asyncio.Event()

        async def strange(path: Path, message: dict[str, object]) -> dict[str, object]:
            asked.append(message)
            if len(asked) == 3:
                third.set()
            return {"ok": True}  # a status without its fields

        hub = Hub(Path("unused.sock"), poll=0.0, asker=strange)
        polling = asyncio.create_task(hub.run())
        await asyncio.wait_for(third.wait(), TIMEOUT)
        ran = len(live.events.periods)  # the live hub polls every 0.05 s, as a period runs
        async with asyncio.timeout(TIMEOUT):
            while len(live.events.periods) < ran + 4:
                await asyncio.sleep(0.01)
        polling.cancel()
        with pytest.raises(asyncio.CancelledError):
            await polling
        return len(asked)

    assert asyncio.run(polled_on()) >= 3
    said = [r for r in caplog.records if "polling on" in r.getMessage()]
    assert len(said) == 1 and "KeyError" in said[0].getMessage()  # once, not at every poll


@pytest.mark.parametrize(
    ("host", "answered"),
    [
        ("rebind.attacker.example", False),  # a page whose own name now resolves to the Pi
        ("localhost.attacker.example:8080", False),
        ("localhost:80x", False),
        ("", False),
        ("localhost:8080", True),
        ("LOCALHOST.", True),
        ("127.0.0.1:8080", True),
        ("192.168.1.50", True),  # the Pi's address on the LAN, as a phone opens it
        ("[::1]:8080", True),
    ],
)
def test_the_page_answers_only_to_this_machines_names_and_addresses(
    live: Site, host: str, answered: bool
) -> None:
    with _client(live) as client:
        page = client.get("/", headers={"host": host})
        history = client.get("/api/history", headers={"host": host})
    if answered:
        assert (page.status_code, history.status_code) == (200, 200)
        return
    assert (page.status_code, history.status_code) == (400, 400)
    assert history.text == (
        f"this page does not answer to the host name {host!r}: open it by the Pi's address, "
        "or add the name to web.allowed_hosts\n"
    )


def test_the_allowed_host_names_are_this_machines_unless_the_config_lists_them(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(socket, "gethostname", lambda: "brewpi")
    where = tmp_path / "control.sock"
    default = settings_from(config_read.parse(edited(BASE, web__read_only_view="on")), where)
    assert default.hosts == ("localhost", "brewpi", "*.local")
    for host in ("brewpi:8080", "brewpi.local", "brewpi-2.local:8080"):  # mDNS renames
        assert host_allowed(host, default.hosts), host
    assert not host_allowed("brewpi.local.attacker.example", default.hosts)
    listed = edited(BASE, web__read_only_view="on", web__allowed_hosts="[brew.example.org]")
    behind_a_proxy = settings_from(config_read.parse(listed), where)
    assert behind_a_proxy.hosts == ("brew.example.org",)
    assert not host_allowed("brewpi.local", behind_a_proxy.hosts)
    assert host_allowed("10.0.0.7:8080", behind_a_proxy.hosts)


@pytest.mark.parametrize("path", ["/api/login", "/api/logout", "/api/command", "/api/program"])
def test_a_deeply_nested_body_is_refused_in_one_line_before_it_is_parsed(
    live: Site, path: str
) -> None:
    # 1500 '[' made json.loads raise RecursionError: a 500 and a traceback per request.
    with _client(live) as client:
        reply = client.post(path, content=b"[" * 1500, headers={"content-type": "application/json"})
    assert reply.status_code == 400
    assert reply.json() == {
        "ok": False,
        "error": f"the request is not acceptable JSON: nested deeper than {MAX_DEPTH} levels",
    }


@contextlib.contextmanager
def _uvicorn_log(caplog: pytest.LogCaptureFixture) -> Iterator[None]:
    """What uvicorn logs reaches `caplog` too (its logger does not propagate to the root)."""
    logger = logging.getLogger("uvicorn.error")
    logger.addHandler(caplog.handler)
    try:
        yield
    finally:
        logger.removeHandler(caplog.handler)


def test_an_unexpected_failure_is_a_one_line_500_logged_here_and_the_server_goes_on(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    app = create_app(WebSettings(tmp_path / "control.sock", STORED, 3600.0, True))

    def torn() -> tuple[bytes, bytes]:
        raise RuntimeError("mirror torn")

    app.state.hub.history_body = torn
    with _uvicorn_log(caplog), served(app) as url, httpx.Client(base_url=url) as client:
        replies = [client.get("/api/history") for _ in range(3)]
        page = client.get("/")
    for reply in replies:
        assert reply.status_code == 500
        assert reply.json() == {
            "ok": False,
            "error": "the server failed on this request (RuntimeError): see its log",
        }
    assert page.status_code == 200  # the server goes on
    said = [r for r in caplog.records if "failed" in r.getMessage()]
    assert [r.getMessage() for r in said] == [
        "web: GET /api/history failed: RuntimeError('mirror torn')",
        "web: GET /api/history failed: RuntimeError('mirror torn') (again)",
        "web: GET /api/history failed: RuntimeError('mirror torn') (again)",
    ]
    assert said[0].exc_info is not None and all(r.exc_info is None for r in said[1:])
    assert [r for r in caplog.records if r.name.startswith("uvicorn")] == []


def test_a_new_x_forwarded_for_with_each_try_is_still_one_client(tmp_path: Path) -> None:
    """X-Forwarded-For is anyone's to send: trusted, 100 tries each naming a new address got
    GLOBAL_BURST wrong passwords checked and spent everyone's logins, the owner's too."""
    settings = WebSettings(tmp_path / "control.sock", STORED, 3600.0, True)
    app = create_app(settings, clock=lambda: 100.0)  # no attempt earned back meanwhile
    with served(app) as url, httpx.Client(base_url=url, timeout=TIMEOUT) as client:
        # The reverse proxy on this machine says the browser used TLS: the cookie is Secure.
        owner = client.post(
            "/api/login", json={"password": PASSWORD}, headers={"x-forwarded-proto": "https"}
        )
        tries = [
            client.post(
                "/api/login",
                json={"password": f"guess {i}"},
                headers={"x-forwarded-for": f"10.{i}.0.1"},
            )
            for i in range(100)
        ]
    assert owner.status_code == 200 and "secure" in owner.headers["set-cookie"].lower()
    # Five checked (the right one before them gave its attempt back), then one client waits.
    statuses = [reply.status_code for reply in tries]
    assert statuses == [401] * LOGIN_BURST + [429] * (100 - LOGIN_BURST)
    assert LOGIN_BURST < GLOBAL_BURST  # so others could still log in


def _closed_by_server(sock: socket.socket) -> bool:
    """Whether the server closes `sock` without answering (before TIMEOUT)."""
    sock.settimeout(TIMEOUT)
    try:
        return sock.recv(1024) == b""
    except TimeoutError:
        return False


def test_a_half_sent_request_is_closed_at_the_request_deadline(tmp_path: Path) -> None:
    """uvicorn timed out only idle connections: 50 half-sent requests stayed open. Waits on
    the server's own timer, in real time: the deadline is set short (0.3 s) for the test."""
    deadline = 0.3
    app = create_app(WebSettings(tmp_path / "control.sock", STORED, 3600.0, True))
    half_headers = b"GET / HTTP/1.1\r\nHost: localhost\r\nAccept: text/"
    half_body = (
        b"POST /api/login HTTP/1.1\r\nHost: localhost\r\nContent-Type: application/json\r\n"
        b"Content-Length: 40\r\n\r\n" + b'{"password": "'
    )
    whole = b"GET /favicon.ico HTTP/1.1\r\nHost: localhost\r\n\r\n"
    with served(app, request_timeout=deadline) as url:
        address = ("127.0.0.1", int(url.rsplit(":", 1)[1]))
        for sent in (half_headers, half_body, whole + half_headers):
            with socket.create_connection(address) as sock:
                began = time.monotonic()
                sock.sendall(sent)
                if sent.startswith(whole):  # answered, then the next one half sent
                    sock.settimeout(TIMEOUT)
                    assert sock.recv(1024).startswith(b"HTTP/1.1 204 ")
                assert _closed_by_server(sock), sent
                assert time.monotonic() - began >= deadline - 0.01


def test_connections_beyond_the_limit_are_closed_at_once(tmp_path: Path) -> None:
    app = create_app(WebSettings(tmp_path / "control.sock", STORED, 3600.0, True))
    request = b"GET /favicon.ico HTTP/1.1\r\nHost: localhost\r\n\r\n"
    with served(app, request_timeout=TIMEOUT * 10, max_connections=2) as url:
        address = ("127.0.0.1", int(url.rsplit(":", 1)[1]))
        with (
            socket.create_connection(address) as first,
            socket.create_connection(address) as second,
        ):
            for sock in (first, second):  # both served
                sock.sendall(request)
                sock.settimeout(TIMEOUT)
                assert sock.recv(1024).startswith(b"HTTP/1.1 204 ")
            with socket.create_connection(address) as third:
                assert _closed_by_server(third)  # long before the request deadline
        assert _answered_soon(address, request)  # the two closed: room again


def _answered_soon(address: tuple[str, int], request: bytes) -> bool:
    """Whether a new connection's `request` is answered within TIMEOUT (tried again while the
    server may not yet have seen connections just closed go)."""
    deadline = time.monotonic() + TIMEOUT
    while time.monotonic() < deadline:
        with socket.create_connection(address) as sock:
            sock.sendall(request)
            sock.settimeout(TIMEOUT)
            with contextlib.suppress(ConnectionError):
                if sock.recv(1024).startswith(b"HTTP/1.1 204 "):
                    return True
    return False


class _Daemon:
    """A daemon as the hub asks it, period `t` the last run (one history row a period, of 5 s);
    `answering` False: its socket refuses; `hung`: a request is never answered."""

    def __init__(self) -> None:
        self.t = 1000.0
        self.answering = True
        self.hung = False

    async def __call__(self, path: Path, message: dict[str, object]) -> dict[str, object]:
        if self.hung:
            await asyncio.Event().wait()
        if not self.answering:
            raise DaemonUnavailable(f"no hermsd is running: nothing answers on {path}")
        if message["cmd"] == "status":
            return {"ok": True, "tun": "HLT", "t": self.t, "pv": 66.0, "state": "ok"}
        return {"ok": True, "period": 5.0, "more": False, "rows": [[self.t, 66.0, 66.0, 9, 9]]}


def _first(queue: asyncio.Queue[bytes | None]) -> dict[str, Any]:
    event = queue.get_nowait()
    assert event is not None and event.startswith(b"data: ")
    decoded: dict[str, Any] = json.loads(event[len(b"data: ") :])
    return decoded


def test_every_event_says_how_old_its_reading_is_by_the_hubs_clock() -> None:
    daemon, now = _Daemon(), [50.0]
    hub = Hub(Path("hermsd.sock"), asker=daemon, clock=lambda: now[0])

    async def seen() -> list[dict[str, Any]]:
        await hub.refresh()  # period 1000 comes at 50 s
        open_at_start = hub.open_page(None)
        now[0] = 53.0
        events = [_first(open_at_start), _first(hub.open_page(None))]
        now[0] = 59.5  # the daemon answers, but its loop has run no period since
        await hub.refresh()
        events.append(_first(hub.open_page(None)))
        daemon.t, now[0] = 1005.0, 60.0  # a period runs: pushed as it comes
        await hub.refresh()
        events.append(_first(open_at_start))
        return events

    at_start, three_s_later, stalled, pushed = asyncio.run(seen())
    assert [e["age"] for e in (at_start, three_s_later, stalled, pushed)] == [0.0, 3.0, 9.5, 0.0]
    assert all(e["stale_after"] == 2 * 5.0 for e in (at_start, three_s_later, stalled, pushed))
    assert stalled["status"]["t"] == 1000.0 and pushed["status"]["t"] == 1005.0


def test_a_page_opened_after_the_daemon_stopped_is_told_so_not_its_last_status() -> None:
    daemon, now = _Daemon(), [50.0]
    hub = Hub(Path("hermsd.sock"), asker=daemon, clock=lambda: now[0])
    stopped = "no hermsd is running: nothing answers on hermsd.sock"

    async def seen() -> tuple[list[dict[str, Any]], dict[str, Any], dict[str, Any]]:
        await hub.refresh()
        open_then = hub.open_page(None)
        daemon.answering, now[0] = False, 51.0
        await hub.refresh()
        told = [_first(open_then), _first(open_then)]
        now[0] = 400.0  # much later, a phone wakes up
        woken = _first(hub.open_page(1000.0))
        daemon.answering = True  # started again; its loop has not run a period yet
        await hub.refresh()
        return told, woken, _first(open_then)

    (before, at_stop), woken, again = asyncio.run(seen())
    assert "status" in before
    assert at_stop == {"error": stopped, "age": 1.0, "stale_after": 10.0}
    assert woken == {"error": stopped, "age": 350.0, "stale_after": 10.0}  # no status
    # Answering again: the pages hear it at once, with how old the status is.
    assert again["status"]["t"] == 1000.0 and again["age"] == 350.0


def test_a_daemon_that_does_not_answer_for_two_periods_is_not_taken_as_live() -> None:
    daemon, now = _Daemon(), [50.0]
    hub = Hub(Path("hermsd.sock"), asker=daemon, clock=lambda: now[0])

    async def seen() -> list[dict[str, Any]]:
        await hub.refresh()
        daemon.hung = True  # its socket takes the request; no answer comes
        polling = asyncio.create_task(hub.refresh())
        await asyncio.sleep(0)
        now[0] = 60.0  # two periods: still live, just
        at_two = _first(hub.open_page(None))
        now[0] = 60.5
        beyond = _first(hub.open_page(None))
        polling.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await polling
        return [at_two, beyond]

    at_two, beyond = asyncio.run(seen())
    assert at_two["age"] == 10.0 and at_two["status"]["t"] == 1000.0
    assert beyond == {"error": "hermsd has not answered for 10 s", "age": 10.5, "stale_after": 10.0}


def _first_event(client: httpx.Client) -> dict[str, Any]:
    with client.stream("GET", "/api/events") as stream:
        line = next(line for line in stream.iter_lines() if line.startswith("data: "))
    decoded: dict[str, Any] = json.loads(line[len("data: ") :])
    return decoded


def test_a_page_opened_after_the_real_daemon_stopped_gets_no_status(tmp_path: Path) -> None:
    with site(tmp_path) as served_site, _client(served_site) as client:
        first = _first_event(client)
        assert "status" in first and first["age"] < served_site.hub.stale_after()
        served_site.stop_answering()
        first = _first_event(client)
    assert first["error"].startswith("no hermsd is running") and "status" not in first
