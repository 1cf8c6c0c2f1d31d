"""Alerts: the command runs off the control thread, bounded in time and rate, failures told."""

from __future__ import annotations

import dataclasses
import json
import os
import sys
import threading
from pathlib import Path
from typing import Any

import pytest

from hermsd.config import schema as config_module
from hermsd.config.read import parse
from hermsd.config.schema import AlertsConfig, Config, ConfigError
from hermsd.runtime.alerts import Alerts, Event
from hermsd.runtime.assemble import assemble
from hermsd.runtime.daemon import Daemon
from hermsd.sim.clock import VirtualClock
from hermsd.sim.world import build_world
from tests.test_daemon import Periods

WAIT = 10.0  # s of real time a worker gets to finish: a bound, never a sleep

# A child that appends what it was given (stdin, and the HERMSD_* variables) to a file.
RECORDER = (
    "import json, os, sys; "
    "env = {k: v for k, v in os.environ.items() if k.startswith('HERMSD_')}; "
    "line = json.dumps({'stdin': sys.stdin.read(), 'env': env}); "
    "open(sys.argv[1], 'a').write(line + '\\n')"
)


def recording(path: Path) -> tuple[str, ...]:
    return (sys.executable, "-c", RECORDER, str(path))


def received(path: Path) -> list[dict[str, Any]]:
    return [json.loads(line) for line in path.read_text().splitlines()]


class Said:
    """Collects the warnings alerts give (from the worker thread, too)."""

    def __init__(self) -> None:
        self.lines: list[str] = []
        self._lock = threading.Lock()

    def __call__(self, line: str) -> None:
        with self._lock:
            self.lines.append(line)


EVENT = Event(
    "alarm_raised",
    "ALARM overtemp: 96.1 °C above safety.max_temp 95 °C; heater off",
    "HLT",
    1_700_000_000 * 10**9,  # 2023-11-14 22:13:20 UTC
    kind="overtemp",
    pv=96.125,
    setpoint=66.0,
    output=0.0,
)


def test_the_child_gets_the_event_as_json_on_stdin_and_in_its_environment(tmp_path: Path) -> None:
    out = tmp_path / "got"
    said = Said()
    alerts = Alerts(AlertsConfig(command=recording(out)), said)
    alerts.start()
    alerts.send(EVENT, 0.0)
    assert alerts.close(WAIT)
    [got] = received(out)
    assert json.loads(got["stdin"]) == {
        "event": "alarm_raised",
        "message": "ALARM overtemp: 96.1 °C above safety.max_temp 95 °C; heater off",
        "tun": "HLT",
        "wall_ns": 1_700_000_000_000_000_000,
        "kind": "overtemp",
        "pv": 96.125,
        "setpoint": 66.0,
        "output": 0.0,
        "suppressed": 0,
        "time": "2023-11-14T22:13:20Z",
    }
    assert got["env"] == {
        "HERMSD_EVENT": "alarm_raised",
        "HERMSD_KIND": "overtemp",
        "HERMSD_MESSAGE": "ALARM overtemp: 96.1 °C above safety.max_temp 95 °C; heater off",
        "HERMSD_TUN": "HLT",
        "HERMSD_PV": "96.12",  # two decimals, as the status line; 96.125 rounds to even
        "HERMSD_SETPOINT": "66.00",
        "HERMSD_OUTPUT": "0.00",
        "HERMSD_TIME": "2023-11-14T22:13:20Z",
        "HERMSD_SUPPRESSED": "0",
    }
    assert said.lines == []


def test_an_unknown_pv_is_null_in_json_and_empty_in_the_environment(tmp_path: Path) -> None:
    out = tmp_path / "got"
    alerts = Alerts(AlertsConfig(command=recording(out)), Said())
    alerts.start()
    alerts.send(dataclasses.replace(EVENT, pv=None), 0.0)
    assert alerts.close(WAIT)
    [got] = received(out)
    assert json.loads(got["stdin"])["pv"] is None and got["env"]["HERMSD_PV"] == ""


@pytest.mark.parametrize(
    ("command", "words"),
    [
        (("false",), "alert command for alarm_raised failed with exit status 1"),
        (
            (sys.executable, "-c", "import sys; sys.exit('no route to ntfy.sh')"),
            "status 1: no route",
        ),
        (("/nonexistent/hermsd-alert",), "could not start '/nonexistent/hermsd-alert'"),
        (("sleep", "60"), "alert command for alarm_raised killed after 0.2 s (alerts.timeout)"),
        (
            (sys.executable, "-c", "import os, signal; os.kill(os.getpid(), signal.SIGTERM)"),
            "alert command for alarm_raised killed by SIGTERM",
        ),
    ],
)
def test_a_failing_command_is_reported(command: tuple[str, ...], words: str) -> None:
    said = Said()
    alerts = Alerts(AlertsConfig(command=command, timeout=0.2), said)
    alerts.start()
    alerts.send(EVENT, 0.0)
    assert alerts.close(WAIT)
    assert len(said.lines) == 1 and words in said.lines[0], said.lines
    assert alerts.failed == 1


def test_the_rate_limit_holds_back_and_counts_events_of_one_kind(tmp_path: Path) -> None:
    out = tmp_path / "got"
    alerts = Alerts(AlertsConfig(command=recording(out), min_interval=60.0), Said())
    alerts.start()
    other_kind = dataclasses.replace(EVENT, kind="dry_fire")
    alerts.send(EVENT, 0.0)  # sent
    alerts.send(EVENT, 10.0)  # held back
    alerts.send(other_kind, 20.0)  # sent: another kind
    alerts.send(EVENT, 59.9)  # held back
    alerts.send(EVENT, 60.0)  # sent, 60 s after the last one sent, counting two held back
    alerts.send(EVENT, 100.0)  # held back: 40 s after the last one sent
    assert alerts.close(WAIT)
    sent = [json.loads(got["stdin"]) for got in received(out)]
    assert [(e["kind"], e["suppressed"]) for e in sent] == [
        ("overtemp", 0),
        ("dry_fire", 0),
        ("overtemp", 2),
    ]


CLEARED = dataclasses.replace(EVENT, event="alarm_cleared", message="overtemp cleared")


def limited(out: Path) -> Alerts:
    """Alerts at most one a minute of each event and kind, recorded to `out`."""
    alerts = Alerts(AlertsConfig(command=recording(out), min_interval=60.0), Said())
    alerts.start()
    return alerts


def events_sent(alerts: Alerts, out: Path) -> list[tuple[str, int]]:
    assert alerts.close(WAIT)
    sent = [json.loads(got["stdin"]) for got in received(out)]
    return [(e["event"], e["suppressed"]) for e in sent]


def test_an_alarm_raised_again_soon_after_it_cleared_is_sent_once_its_interval_passes(
    tmp_path: Path,
) -> None:
    out = tmp_path / "got"
    alerts, cleared = limited(out), CLEARED
    alerts.send(EVENT, 0.0)  # sent
    alerts.send(cleared, 20.0)  # sent: another event
    alerts.send(EVENT, 40.0)  # held back: and then nothing more all day
    alerts.flush(59.9)  # not yet
    alerts.flush(60.0)  # 60 s after the last raised one sent: the standing alarm is said
    alerts.flush(200.0)  # once
    assert events_sent(alerts, out) == [
        ("alarm_raised", 0),
        ("alarm_cleared", 0),
        ("alarm_raised", 0),
    ]


def test_a_held_back_event_that_later_news_of_its_kind_made_moot_is_only_counted(
    tmp_path: Path,
) -> None:
    out = tmp_path / "got"
    alerts, cleared = limited(out), CLEARED
    alerts.send(EVENT, 0.0)  # sent
    alerts.send(cleared, 10.0)  # sent
    alerts.send(EVENT, 20.0)  # held back
    alerts.send(cleared, 30.0)  # held back: the latest news, and it is "cleared"
    alerts.flush(60.0)  # the raised one is moot: not sent
    alerts.flush(70.0)  # the cleared one is due: sent, counting nothing before it
    alerts.send(EVENT, 80.0)  # sent, 80 s after the last raised one, counting the moot one
    assert events_sent(alerts, out) == [
        ("alarm_raised", 0),
        ("alarm_cleared", 0),
        ("alarm_cleared", 0),
        ("alarm_raised", 1),
    ]


def test_events_not_chosen_and_no_command_run_nothing(tmp_path: Path) -> None:
    out = tmp_path / "got"
    alerts = Alerts(AlertsConfig(command=recording(out), events=("started",)), Said())
    alerts.start()
    alerts.send(EVENT, 0.0)
    alerts.config = AlertsConfig(command=None)
    alerts.send(dataclasses.replace(EVENT, event="started"), 1.0)
    assert alerts.close(WAIT)
    assert not out.exists()


def test_a_reload_applies_the_alerts_section_to_the_events_that_follow(tmp_path: Path) -> None:
    out = tmp_path / "got"
    daemon, clock, world = alerting_daemon(AlertsConfig())  # no command: no worker
    clock.call_at(1000.0, lambda: world.chip.set_fault("nack"))
    new = dataclasses.replace(daemon.config, alerts=AlertsConfig(command=recording(out)))
    with daemon:
        daemon.run(until=100.0)
        daemon.reload(new)
        daemon.run(until=1100.0)
    seen = [json.loads(got["stdin"])["event"] for got in received(out)]
    assert seen == ["alarm_raised", "alarm_raised", "stopped"]  # sensor_fault, stale_reading


def test_a_full_queue_drops_the_event_and_says_so() -> None:
    said = Said()
    alerts = Alerts(AlertsConfig(command=("true",), min_interval=0.0), said, queue_size=2)
    # No worker: nothing takes events off the queue.
    for kind in ("overtemp", "dry_fire", "sensor_fault"):
        alerts.send(dataclasses.replace(EVENT, kind=kind), 0.0)
    assert alerts.dropped == 1
    assert said.lines == ["alert queue full: alarm_raised alert dropped (1 since start)"]


def test_shutdown_waits_a_bounded_time_then_kills_the_command_and_says_what_is_lost() -> None:
    said = Said()
    alerts = Alerts(AlertsConfig(command=("sleep", "60"), timeout=60.0, min_interval=0.0), said)
    alerts.start()
    for kind in ("overtemp", "dry_fire", "sensor_fault"):
        alerts.send(dataclasses.replace(EVENT, kind=kind), 0.0)
    assert not alerts.close(0.2)
    assert (
        "alerts not finished 0.2 s after shutdown: the command running was killed, "
        "2 more left unsent" in said.lines
    )


def test_the_worker_and_its_children_are_not_real_time(tmp_path: Path) -> None:
    """Started from a SCHED_FIFO thread without the reset-on-fork flag, the worker still
    leaves real time, and so does the command it runs."""
    out = tmp_path / "policy"
    script = f"import os; open({str(out)!r}, 'w').write(str(os.sched_getscheduler(0)))"
    alerts = Alerts(AlertsConfig(command=(sys.executable, "-c", script)), Said())
    before = os.sched_getscheduler(0), os.sched_getparam(0)
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
    except PermissionError:
        pytest.skip("real-time scheduling not permitted here")
    try:
        alerts.start()
    finally:
        os.sched_setscheduler(0, *before)
    alerts.send(EVENT, 0.0)
    assert alerts.close(WAIT)
    assert int(out.read_text()) & ~os.SCHED_RESET_ON_FORK == os.SCHED_OTHER


# -- in the daemon ------------------------------------------------------------------------------


def alerting_daemon(alerts: AlertsConfig) -> tuple[Daemon, VirtualClock, Any]:
    default = config_module.DEFAULT
    config = dataclasses.replace(
        default, output=dataclasses.replace(default.output, backend="sim"), alerts=alerts
    )
    clock = VirtualClock()
    world = build_world(config, clock)
    return assemble(config, clock, world.sensor, world.outputs), clock, world


class Logged:
    """A recorder keeping the /hermsd/log messages (written from the worker thread, too)."""

    def __init__(self) -> None:
        self.messages: list[str] = []

    def write(self, topic: str, log_time_ns: int, message: dict[str, Any]) -> None:
        if topic == "/hermsd/log":
            self.messages.append(str(message["message"]))


def test_a_hanging_command_does_not_delay_the_loop_and_is_reported() -> None:
    daemon, clock, world = alerting_daemon(AlertsConfig(command=("sleep", "60"), timeout=60.0))
    logged = Logged()
    daemon.recorder = logged
    periods = Periods()
    daemon.listeners.append(periods)
    clock.call_at(1000.0, lambda: world.chip.set_fault("nack"))
    clock.call_at(1030.0, lambda: world.chip.set_fault("ok"))
    heater_at_the_wait: list[bool] = []
    close = daemon.alerts.close

    def close_soon(timeout: float) -> bool:
        heater_at_the_wait.append(world.outputs.ssr.state)
        return close(0.2)  # the 60 s alerts.timeout shortened for the test

    daemon.alerts.close = close_soon  # type: ignore[method-assign]
    with daemon:
        daemon.run(until=3000.0)
        # The loop went on at every period, on time, while the first child hung.
        times = [record.t for record in periods.records]
        assert times == pytest.approx([5.0 * k for k in range(600)])
        assert daemon.overruns == 0
        assert not [m for m in logged.messages if m.startswith("alert")]
    assert heater_at_the_wait == [False]  # the outputs were off before shutdown waited
    alerts_said = [m for m in logged.messages if m.startswith("alert")]
    assert alerts_said == [
        "alert command for started killed by SIGKILL",
        "alerts not finished 0.2 s after shutdown: the command running was killed, "
        "5 more left unsent",  # two raised, two cleared, stopped
    ]


def test_the_daemon_alerts_start_alarms_and_stop(tmp_path: Path) -> None:
    out = tmp_path / "got"
    daemon, clock, world = alerting_daemon(AlertsConfig(command=recording(out)))
    clock.call_at(1000.0, lambda: world.chip.set_fault("nack"))
    clock.call_at(1030.0, lambda: world.chip.set_fault("ok"))
    with daemon:
        daemon.run(until=1200.0)
    events = [json.loads(got["stdin"]) for got in received(out)]
    seen = [(e["event"], e["kind"]) for e in events]
    assert seen[0] == ("started", "") and seen[-1] == ("stopped", "")
    assert set(seen[1:-1]) == {
        ("alarm_raised", "sensor_fault"),
        ("alarm_raised", "stale_reading"),
        ("alarm_cleared", "sensor_fault"),
        ("alarm_cleared", "stale_reading"),
    }
    raised = next(e for e in events if e["event"] == "alarm_raised")
    assert raised["tun"] == "HLT" and raised["setpoint"] == 66.0 and raised["output"] == 0.0
    assert events[-1]["message"] == "heater off: stopped"


def test_the_stop_alert_says_the_outputs_are_off_whatever_was_asked_before(
    tmp_path: Path,
) -> None:
    """Stopped while heating at full power: the alert tells the output in force, 0 %."""
    out = tmp_path / "got"
    daemon, _clock, _world = alerting_daemon(AlertsConfig(command=recording(out)))
    with daemon:
        daemon.run(until=300.0)  # 20 °C water, setpoint 66 °C: full power
        assert daemon.output == 100.0
    stopped = received(out)[-1]
    event = json.loads(stopped["stdin"])
    assert (event["event"], event["output"]) == ("stopped", 0.0)
    assert stopped["env"]["HERMSD_OUTPUT"] == "0.00"


# -- the config section -------------------------------------------------------------------------


def problem(text: str) -> str:
    with pytest.raises(ConfigError) as caught:
        parse(text, "hermsd.yaml")
    return str(caught.value)


def test_the_alerts_section_reads_an_argv_list() -> None:
    config: Config = parse(
        "alerts:\n  command: [curl, -d, '@-', 'https://ntfy.sh/hlt']\n  timeout: 5\n"
    )
    assert config.alerts.command == ("curl", "-d", "@-", "https://ntfy.sh/hlt")
    assert config.alerts.timeout == 5.0
    relative = parse("alerts:\n  command: [bin/alert]\n")  # found from the working directory
    assert relative.alerts.command == ("bin/alert",)


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("alerts:\n  command: []\n", "hermsd.yaml:2:12: alerts.command: is an empty list"),
        ("alerts:\n  command: curl -d @-\n", "2:12: alerts.command: expected a list such as"),
        ("alerts:\n  command: [curl, 5]\n", "2:19: alerts.command: item 2: expected text, got"),
        ("alerts:\n  command: [curl, '']\n", "2:19: alerts.command: item 2: is empty"),
        ("alerts:\n  command: [[curl]]\n", "2:13: alerts.command: item 1: expected a single"),
        ("alerts:\n  events: [started, stoped]\n", "2:21: alerts.events: item 2: 'stoped' is no"),
        ("alerts:\n  events: [started, started]\n", "alerts.events: names a choice twice"),
        ("alerts:\n  events: []\n", "2:11: alerts.events: is an empty list"),
        ("alerts:\n  timeout: 0.5\n", "2:12: alerts.timeout: 0.5 s is out of range"),
        ("alerts:\n  timeout: '10'\n", "alerts.timeout: expected a number"),
        ("alerts:\n  shell: true\n", "2:3: alerts.shell: unknown key"),
    ],
)
def test_the_alerts_section_is_checked_like_the_rest(text: str, words: str) -> None:
    assert words in problem(text)
