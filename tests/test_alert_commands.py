"""The ready-made alert commands of docs/alerts.md, as written there, run by hermsd's own
alert worker for an alarm, against local stand-ins for ntfy, Pushover, Telegram and an SMTP
server: only the service's address and the secrets' folder are changed."""

from __future__ import annotations

import re
import socket
import threading
import urllib.parse
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any, ClassVar

import pytest

from hermsd.config.schema import AlertsConfig
from hermsd.runtime.alerts import Alerts, Event

DOC = Path(__file__).resolve().parents[1] / "docs" / "alerts.md"
ALARM = Event(
    "alarm_raised",
    "ALARM over_temperature: 96.12 °C at or above the limit 95.0 °C; heater off",
    "HLT",
    1_700_000_000_000_000_000,
    kind="over_temperature",
    pv=96.125,
    setpoint=66.0,
    output=0.0,
)
SAID = "ALARM over_temperature: 96.12 °C at or above the limit 95.0 °C; heater off"


def script(name: str) -> str:
    """The script docs/alerts.md gives for /usr/local/bin/`name`."""
    blocks = re.findall(r"```sh\n(#!/bin/sh\n# (\S+):.*?)```", DOC.read_text("utf-8"), re.S)
    return next(text for text, named in blocks if named == name)


def installed(tmp_path: Path, name: str, replace: dict[str, str]) -> Path:
    text = script(name).replace("/etc/hermsd/", f"{tmp_path}/")
    for old, new in replace.items():
        assert old in text, old
        text = text.replace(old, new)
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    path.chmod(0o755)
    for secret in ("pushover-token", "pushover-user", "telegram-token", "mail-password"):
        (tmp_path / secret).write_text(f"{secret}-value\n", encoding="utf-8")
    return path


def run(command: Path) -> list[str]:
    """Run `command` for the alarm as the daemon does; the warnings it gave."""
    warnings: list[str] = []
    alerts = Alerts(AlertsConfig(command=(str(command),), timeout=10.0), warnings.append)
    alerts.start()
    alerts.send(ALARM, 0.0)
    assert alerts.close(10.0)
    return warnings


class Recorded(BaseHTTPRequestHandler):
    requests: ClassVar[list[dict[str, Any]]] = []

    def do_POST(self) -> None:
        body = self.rfile.read(int(self.headers["Content-Length"]))
        self.requests.append({"path": self.path, "headers": dict(self.headers), "body": body})
        self.send_response(200)
        self.send_header("Content-Length", "2")
        self.end_headers()
        self.wfile.write(b"{}")

    def log_message(self, *args: Any) -> None:
        pass


@pytest.fixture
def http() -> Iterator[tuple[str, list[dict[str, Any]]]]:
    Recorded.requests = []
    server = ThreadingHTTPServer(("127.0.0.1", 0), Recorded)
    thread = threading.Thread(target=server.serve_forever)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}", Recorded.requests
    finally:
        server.shutdown()
        thread.join()
        server.server_close()


def test_ntfy_gets_an_urgent_message_with_the_alarm(tmp_path: Path, http: Any) -> None:
    url, requests = http
    command = installed(tmp_path, "hermsd-ntfy", {"https://ntfy.sh": url})
    assert run(command) == []
    (request,) = requests
    assert request["path"] == "/hermsd-change-me-to-something-long-and-random"
    assert request["headers"]["Title"] == "HLT alarm_raised"
    assert request["headers"]["Priority"] == "urgent"
    assert request["body"].decode() == f"{SAID} (PV 96.12 °C, setpoint 66.00 °C)"


def test_pushover_gets_the_token_user_and_a_high_priority(tmp_path: Path, http: Any) -> None:
    url, requests = http
    replace = {"https://api.pushover.net": url}
    assert run(installed(tmp_path, "hermsd-pushover", replace)) == []
    (request,) = requests
    assert request["path"] == "/1/messages.json"
    fields = dict(
        re.findall(rb'name="(\w+)"\r\n\r\n(.*?)\r\n--', request["body"], re.S)  # multipart
    )
    assert fields == {
        b"token": b"pushover-token-value",
        b"user": b"pushover-user-value",
        b"priority": b"1",
        b"title": b"HLT alarm_raised",
        b"message": f"{SAID} (PV 96.12 °C, setpoint 66.00 °C)".encode(),
    }


def test_telegram_gets_the_chat_and_the_text(tmp_path: Path, http: Any) -> None:
    url, requests = http
    replace = {"https://api.telegram.org": url}
    assert run(installed(tmp_path, "hermsd-telegram", replace)) == []
    (request,) = requests
    assert request["path"] == "/bottelegram-token-value/sendMessage"
    assert urllib.parse.parse_qs(request["body"].decode()) == {
        "chat_id": ["123456789"],
        "text": [f"HLT alarm_raised: {SAID} (PV 96.12 °C, setpoint 66.00 °C)"],
    }


class SmtpStandIn:
    """The least of an SMTP server (RFC 5321): it takes one mail and keeps it."""

    def __init__(self) -> None:
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.port = self.listener.getsockname()[1]
        self.commands: list[str] = []
        self.data = b""
        self.thread = threading.Thread(target=self._serve)
        self.thread.start()

    def _serve(self) -> None:
        conn, _ = self.listener.accept()
        with conn, conn.makefile("rb") as lines:
            conn.sendall(b"220 stand-in ESMTP\r\n")
            for raw in lines:
                line = raw.decode().rstrip("\r\n")
                self.commands.append(line)
                verb = line.split(" ")[0].upper()
                if verb == "DATA":
                    conn.sendall(b"354 go on\r\n")
                    while (raw := lines.readline()) != b".\r\n":
                        self.data += raw
                    conn.sendall(b"250 queued\r\n")
                elif verb == "QUIT":
                    conn.sendall(b"221 bye\r\n")
                    return
                else:
                    conn.sendall(b"250 ok\r\n")

    def close(self) -> None:
        self.thread.join(10.0)
        self.listener.close()


def test_mail_is_sent_by_smtp_with_the_event_in_its_subject(tmp_path: Path) -> None:
    server = SmtpStandIn()
    try:
        replace = {"smtps://smtp.example.org:465": f"smtp://127.0.0.1:{server.port}"}
        assert run(installed(tmp_path, "hermsd-mail", replace)) == []
    finally:
        server.close()
    assert "MAIL FROM:<hermsd@example.org>" in server.commands
    assert "RCPT TO:<brewer@example.org>" in server.commands
    mail = server.data.decode()
    assert "Subject: HLT alarm_raised\r\n" in mail and "To: brewer@example.org\r\n" in mail
    assert f"{SAID}\r\n\r\nPV 96.12 °C, setpoint 66.00 °C, output 0.00 %" in mail


def test_a_service_that_refuses_is_a_warning(tmp_path: Path) -> None:
    with socket.create_server(("127.0.0.1", 0)) as closed:
        port = closed.getsockname()[1]
    command = installed(tmp_path, "hermsd-ntfy", {"https://ntfy.sh": f"http://127.0.0.1:{port}"})
    (warning,) = run(command)
    assert warning.startswith("alert command for alarm_raised failed with exit status 7: curl")
