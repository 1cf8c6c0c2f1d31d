"""The MQTT bridge: the daemon's state to a broker, and Home Assistant's commands back.

It is a process of its own and reaches the daemon only through the control socket, as
`hermsd status` and `hermsd set` do, so nothing it does (a slow broker, a flood of messages,
a crash) can delay the control loop.

Three threads. paho-mqtt's network thread keeps the broker connection: it reconnects with
doubling waits, and at each connection publishes the discovery messages, the availability
and the last state again (retained; a restarted broker without persistence has lost them).
It checks each command as it arrives and keeps the valid ones, the latest of each topic
only: a setpoint or a mode is the brewer's last intent, so a newer one replaces one not yet
sent (a slider dragged sends many). The main thread asks the daemon for its status every
`poll` seconds and publishes the state when a new control period has run. The command thread
sends the kept commands, oldest topic first, no faster than the daemon takes a client's
requests (`RequestLimit`: it waits, and what arrives meanwhile replaces what waits): a `set`
is answered only after the next period boundary, and neither the broker nor the polls may
wait for it. When the
daemon does not answer, the availability turns "offline" and the polls back off to
`DAEMON_RETRY_MAX`; a bridge that dies leaves "offline" behind as its last will.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import ssl
import threading
import time
from pathlib import Path
from typing import Any

import paho.mqtt.client as mqtt
from paho.mqtt.enums import CallbackAPIVersion
from paho.mqtt.properties import Properties
from paho.mqtt.reasoncodes import ReasonCode

from hermsd.api.client import NoDaemonError, ReplyError, ask, command_timeout
from hermsd.api.protocol import Status, describe
from hermsd.api.server import RequestLimit
from hermsd.config.schema import Config
from hermsd.files import NotRegularFile, read_regular
from hermsd.mqtt import brewday
from hermsd.mqtt.messages import (
    OFFLINE,
    ONLINE,
    Command,
    Refused,
    Topics,
    discovery_messages,
    encode,
    parse_command,
    state_message,
)
from hermsd.runtime.instance import NameLock

log = logging.getLogger("hermsd")

POLL = 0.5  # s between status requests: a state within half a second of its period's end
DAEMON_RETRY_MAX = 10.0  # s: the longest wait between tries while the daemon is gone
BROKER_RETRY = (1, 60)  # s: paho's first and longest wait between connection attempts
KEEPALIVE = 30  # s: the broker fires the last will this long (×1.5) after a silent death
STATUS_TIMEOUT = 2.0  # s: `status` is answered at once from the last period
QOS = 1
PASSWORD_LIMIT = 4096  # bytes in a password file
REFUSED = "refused, nothing changed: "  # as the daemon words its own refusals


class BridgeError(Exception):
    """The bridge cannot start as configured (a password or TLS file it cannot read)."""


class Bridge:
    """Connects the daemon at `socket_path` to the broker `config.mqtt` names."""

    def __init__(
        self,
        config: Config,
        socket_path: Path,
        *,
        poll: float = POLL,
        broker_retry: tuple[int, int] = BROKER_RETRY,
        programs: Path | None = None,
    ) -> None:
        """`programs`: the folder of program files Home Assistant may start (None: none)."""
        settings = config.mqtt
        self.config = config
        self.socket_path = socket_path
        self.poll = poll
        self.topics = Topics.of(settings.topic_prefix, settings.discovery_prefix)
        self.brewday = brewday.BrewdayTopics.of(settings.topic_prefix)
        # The config commands are checked against: the file's, with the daemon's running
        # cut-out once it answers (its setpoints are the thermostat card's range).
        self.checked = config
        self._programs_dir = programs
        self._programs = brewday.list_programs(programs)
        self._chosen: str | None = None  # the program chosen in the select
        self._shown_alarms: list[str] = []  # the alarms of the last state published
        self._news = brewday.News()
        self._discovery = self._discovery_messages()
        # The latest command of each topic not sent yet: {topic: (payload, command)}, in the
        # order the topics first came. A plain lock: `stop` never takes it twice (see there).
        self._pending: dict[str, tuple[bytes, Command]] = {}
        self._wake = threading.Condition(threading.Lock())
        self._limit = RequestLimit()  # the daemon's on this process's commands, kept here
        self._lock = threading.Lock()  # orders what the threads publish
        self._state: bytes | None = None  # the last state published, for reconnections
        self._last_t: float | None = None
        self._available: bool | None = None  # None: not known yet (the first poll says)
        self._stop = threading.Event()
        self._stopping = False  # set first thing in `stop`, before any lock is taken
        client_id = settings.client_id or f"hermsd-{self.topics.node_id}"
        # A broker drops a client when another connects with its id: two bridges of one
        # login would put each other off the broker once a second, for ever.
        self._login = f"{settings.host}:{settings.port} as client id {client_id}"
        self._instance = NameLock(f"mqtt {settings.host}:{settings.port} {client_id}")
        client = mqtt.Client(
            CallbackAPIVersion.VERSION2, client_id=client_id, protocol=mqtt.MQTTv311
        )
        client.will_set(self.topics.availability, OFFLINE, qos=QOS, retain=True)
        if settings.username is not None:
            client.username_pw_set(settings.username, _password(settings.password_file))
        if settings.tls:
            try:
                client.tls_set(
                    ca_certs=settings.ca_file,
                    certfile=settings.cert_file,
                    keyfile=settings.key_file,
                    cert_reqs=ssl.CERT_REQUIRED,
                )
            except (OSError, ssl.SSLError) as error:  # a file missing, unreadable or not PEM
                reason = getattr(error, "strerror", None) or str(error)
                files = [f for f in (settings.ca_file, settings.cert_file, settings.key_file) if f]
                raise BridgeError(f"mqtt TLS files {', '.join(files)}: {reason}") from None
        client.reconnect_delay_set(*broker_retry)
        # A fault in a callback is logged and the network thread goes on (paho's default
        # would end the thread, and with it every reconnection).
        paho_log = logging.getLogger("hermsd.paho")
        paho_log.addFilter(_between_attempts)
        client.enable_logger(paho_log)
        client.suppress_exceptions = True
        client.on_connect = self._on_connect
        client.on_connect_fail = self._on_connect_fail
        client.on_disconnect = self._on_disconnect
        client.on_message = self._on_message
        self.client = client

    # -- the main thread ------------------------------------------------------------------

    def run(self) -> None:
        """Serve until `stop`; then say "offline" and leave the broker cleanly.

        InstanceError, before anything is sent, when another bridge serves this broker and
        client id."""
        self._instance.acquire(
            f"another hermsd mqtt ({{who}}) serves mqtt://{self._login}: one bridge per "
            "broker and client id (two put each other off the broker); stop that one first, "
            "or give this one its own mqtt.client_id"
        )
        try:
            self._serve()
        finally:
            self._instance.release()

    def _serve(self) -> None:
        settings = self.config.mqtt
        log.info(
            "bridging %s to mqtt://%s:%d as %s",
            self.socket_path,
            settings.host,
            settings.port,
            self.topics.prefix,
        )
        self.client.connect_async(settings.host, settings.port, keepalive=KEEPALIVE)
        self.client.loop_start()
        # A daemon thread: a `set` still waiting for its boundary does not hold up the exit.
        threading.Thread(
            target=self._send_commands, name="hermsd-mqtt-commands", daemon=True
        ).start()
        try:
            wait = self.poll
            while not self._stop.is_set():
                wait = self.poll if self._poll() else min(2 * wait, DAEMON_RETRY_MAX)
                self._stop.wait(wait)
        finally:
            with self._lock:
                self._available = False
                info = self.client.publish(self.topics.availability, OFFLINE, QOS, retain=True)
            if self.client.is_connected():
                info.wait_for_publish(timeout=2.0)
            self.client.disconnect()
            self.client.loop_stop()

    def stop(self) -> None:
        """From any thread or a signal handler: `run` returns at once. Only the first call
        acts: a second signal, landing in the handler of the first while it holds the
        commands' lock, would otherwise wait on that lock for ever."""
        if self._stopping:
            return
        self._stopping = True
        self._stop.set()
        with self._wake:
            self._wake.notify_all()

    def _poll(self) -> bool:
        """Publish a new period's state; False when the daemon does not answer."""
        try:
            reply = ask(self.socket_path, Status(), timeout=STATUS_TIMEOUT)
        except (NoDaemonError, ReplyError) as error:
            self._set_available(False, str(error))
            return False
        if not reply["ok"]:  # starting: no period has run yet
            self._set_available(False, str(reply.get("error")))
            return False
        self._set_available(True, "")
        self._follow_the_daemon(reply)
        self._publish_state(reply)
        return True

    def _discovery_messages(self) -> list[tuple[str, bytes]]:
        return [
            (topic, b"" if payload is None else encode(payload))
            for topic, payload in discovery_messages(self.topics, self.checked, self._programs)
        ]

    def _follow_the_daemon(self, status: dict[str, Any]) -> None:
        """Announce again when the daemon's cut-out (the thermostat's range) or the program
        folder's files have changed."""
        below = status.get("setpoint_limits", {}).get("below", self.config.safety.max_temp)
        programs = brewday.list_programs(self._programs_dir)
        if below == self.checked.safety.max_temp and programs == self._programs:
            return
        safety = dataclasses.replace(self.config.safety, max_temp=float(below))
        self.checked = dataclasses.replace(self.config, safety=safety)
        self._programs = programs
        self._discovery = self._discovery_messages()
        log.info(
            "announced again: the daemon's cut-out is %g °C, %d programs",
            below,
            len(programs or []),
        )
        self._announce()

    def _send_commands(self) -> None:
        while True:
            with self._wake:
                self._wake.wait_for(lambda: bool(self._pending) or self._stop.is_set())
            wait = self._limit.wait(os.getpid(), time.monotonic())
            if self._stop.is_set() or (wait > 0.0 and self._stop.wait(wait)):
                return
            with self._wake:  # the latest of the oldest topic, after the wait
                topic = next(iter(self._pending))
                payload, command = self._pending.pop(topic)
            try:
                self._send(topic, payload, command)
            except Exception as error:  # a fault in one command must not end the others
                self._refuse(topic, payload, f"not handled: {_fault(error)}")
            # Charged when the reply is in: the daemon charged it somewhere between the send
            # and the reply, so a bucket charged this late never holds more than the daemon's
            # (charged at the send, a slow answer under load let the next one come too soon).
            self._limit.charge(os.getpid(), time.monotonic())

    def _send(self, topic: str, payload: bytes, command: Command) -> None:
        try:
            reply = ask(self.socket_path, command, command_timeout(self.config.control.period))
        except NoDaemonError as error:
            self._refuse(topic, payload, f"not applied, nothing changed: {error}")
            return
        except ReplyError as error:  # it was sent: the daemon may have applied it
            self._refuse(topic, payload, f"{error}; the next state shows whether it was applied")
            return
        if not reply["ok"]:
            # the daemon's own words ("refused, nothing changed: control.setpoint: ...")
            self._refuse(topic, payload, str(reply.get("error", "refused by hermsd")))
            return
        log.info("applied %s (from mqtt)", describe(command))
        reset = reply.get("reset")
        said = reset["text"] if isinstance(reset, dict) else f"{describe(command)}: applied"
        self._result(topic, True, said)
        self._publish_state(reply)

    def _set_available(self, available: bool, why: str) -> None:
        with self._lock:
            if available == self._available:
                return
            self._available = available
            self._last_t = None  # a daemon started again counts its periods afresh
            self._publish(self.topics.availability, ONLINE if available else OFFLINE)
        if available:
            log.info("hermsd answers on %s: online", self.socket_path)
        else:
            log.warning("%s: offline until it answers", why)

    def _publish_state(self, status: dict[str, Any]) -> None:
        with self._lock:
            if self._last_t is not None and status["t"] <= self._last_t:
                return  # this period's state is out already (a `set` reply after a poll)
            self._last_t = status["t"]
            self._state = encode(state_message(status))
            self._publish(self.topics.state, self._state)
            self._shown_alarms = [str(alarm) for alarm in status["alarms"]]
            for event in self._news.of(status):  # not retained: a restarted HA would fire it
                self.client.publish(self.brewday.event, encode(event), QOS, retain=False)

    # -- paho's network thread ------------------------------------------------------------

    def _on_connect(
        self,
        client: mqtt.Client,
        userdata: Any,
        flags: mqtt.ConnectFlags,
        reason_code: ReasonCode,
        properties: Properties | None,
    ) -> None:
        if reason_code.is_failure:
            log.warning("the broker refused the connection: %s", reason_code)
            return
        log.info("connected to the broker")
        client.subscribe(
            [
                (self.topics.set_setpoint, QOS),
                (self.topics.set_mode, QOS),
                (self.topics.set_pump, QOS),
                (self.topics.home_assistant_status, QOS),
                *((topic, QOS) for topic in self.brewday.commands()),
            ]
        )
        self._announce()

    def _on_connect_fail(self, client: mqtt.Client, userdata: Any) -> None:
        settings = self.config.mqtt
        log.warning("cannot reach the broker at %s:%d: trying again", settings.host, settings.port)

    def _announce(self) -> None:
        """Discovery, availability and the last state, all retained."""
        with self._lock:
            for topic, payload in self._discovery:
                self._publish(topic, payload)
            self._publish(self.topics.availability, ONLINE if self._available else OFFLINE)
            if self._state is not None:
                self._publish(self.topics.state, self._state)
            if self._chosen is not None:
                self._publish(self.brewday.chosen, self._chosen)

    def _on_disconnect(
        self,
        client: mqtt.Client,
        userdata: Any,
        flags: mqtt.DisconnectFlags,
        reason_code: ReasonCode,
        properties: Properties | None,
    ) -> None:
        if not self._stop.is_set():
            log.warning("lost the broker (%s): reconnecting", reason_code)

    def _on_message(self, client: mqtt.Client, userdata: Any, message: mqtt.MQTTMessage) -> None:
        """Take one message; a fault in handling it is said in one line and the next one is
        taken (paho would log a traceback, and a fault in saying so would end its thread)."""
        try:
            self._take(message.topic, bytes(message.payload), bool(message.retain))
        except Exception as error:
            log.error("mqtt message on %s not handled: %s", message.topic, _fault(error))

    def _take(self, topic: str, payload: bytes, retain: bool) -> None:
        if topic == self.topics.home_assistant_status:
            if payload == ONLINE.encode():  # Home Assistant restarted: tell it again
                self._announce()
            return
        if not payload:  # how a retained message is cleared: not a command
            return
        if retain:
            self._refuse(
                topic,
                payload,
                f"{REFUSED}a retained command is not applied: it would be applied again at every "
                "connection (publish it without retain, and clear it with an empty retained "
                "message)",
            )
            return
        try:
            command = self._command(topic, payload)
            if command is None:
                return
        except (Refused, brewday.Refused) as error:
            self._refuse(topic, payload, f"{REFUSED}{error}")
            return
        with self._wake:
            replaced = self._pending.get(topic)
            self._pending[topic] = (payload, command)  # a replaced topic keeps its place
            self._wake.notify_all()
        if replaced is not None:
            log.info(
                "mqtt command on %s: %s replaced by %s before it was sent",
                topic,
                describe(replaced[1]),
                describe(command),
            )

    def _command(self, topic: str, payload: bytes) -> Command | None:
        """The command a message asks for; None for a program chosen (kept here, not sent)."""
        if topic == self.brewday.choose:
            chosen = brewday.choice(payload.decode("utf-8", "replace"), self._programs)
            with self._lock:
                self._chosen = chosen
                self._publish(self.brewday.chosen, chosen)
            return None
        if topic in self.brewday.press.values():
            return brewday.pressed(
                self.brewday,
                topic,
                payload.decode("utf-8", "replace").strip(),
                alarms=self._shown_alarms,
                chosen=self._chosen,
                folder=self._programs_dir,
            )
        return parse_command(self.topics, topic, payload, self.checked)

    # -- either thread --------------------------------------------------------------------

    def _refuse(self, topic: str, payload: bytes, error: str) -> None:
        """Say in the log and on the error topic why a command was not applied (or may not
        have been)."""
        shown = payload[:64].decode("utf-8", "replace")
        log.warning("mqtt command on %s: %s", topic, error)
        message = {"topic": topic, "payload": shown, "error": error}
        self.client.publish(self.topics.error, encode(message), QOS, retain=False)
        self._result(topic, False, error)

    def _result(self, topic: str, ok: bool, text: str) -> None:
        """What became of a command, for the Last command sensor (retained: the last word)."""
        message = {"topic": topic, "ok": ok, "text": text[: brewday.TEXT_LIMIT]}
        self.client.publish(self.brewday.result, encode(message), QOS, retain=True)

    def _publish(self, topic: str, payload: str | bytes) -> None:
        """A retained message, if connected: what is missed is republished on connection."""
        if self.client.is_connected():
            self.client.publish(topic, payload, QOS, retain=True)


def _fault(error: Exception) -> str:
    """An unexpected exception in one line, its kind first: what the journal should say."""
    text = " ".join(str(error).split())[:200]
    return f"{type(error).__name__}: {text}" if text else type(error).__name__


def _between_attempts(record: logging.LogRecord) -> bool:
    """Drop the error paho logs on every turn of its loop between two failed connection
    attempts (its own state, not news; `_on_connect_fail` says the broker is unreachable)."""
    return not record.getMessage().startswith("Client is not connected.")


def _password(path: str | None) -> str | None:
    if path is None:
        return None
    try:
        text = read_regular(path, PASSWORD_LIMIT).decode("utf-8")
    except (OSError, NotRegularFile, UnicodeDecodeError) as error:
        reason = getattr(error, "strerror", None) or str(error)
        raise BridgeError(f"mqtt.password_file {path}: {reason}") from None
    lines = text.splitlines()
    if not lines or not lines[0]:
        raise BridgeError(f"mqtt.password_file {path}: the first line (the password) is empty")
    return lines[0]
