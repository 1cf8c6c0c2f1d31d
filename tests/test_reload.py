"""Edits of the config file while the loop runs, on the virtual clock.

The daemon polls the file once a control period; these tests edit a real file in a temporary
directory between periods, as an editor would, and watch what the loop does next.
"""

from __future__ import annotations

import itertools
import os
import re
import threading
from concurrent.futures import Future
from pathlib import Path
from typing import Any

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from test_config import assert_within_spec, documents, mutated_config

from hermsd.config import read
from hermsd.config import schema as config_module
from hermsd.config.file import Check, ConfigFile, Start, at_once, in_thread
from hermsd.runtime.assemble import assemble
from hermsd.runtime.daemon import Daemon
from hermsd.runtime.period import PeriodRecord
from hermsd.runtime.saver import Saver
from hermsd.safety.latches import LatchStore
from hermsd.safety.limits import Alarm
from hermsd.sim.clock import VirtualClock
from hermsd.sim.hlt import FoptdPlant, Plant
from hermsd.sim.mash import HermsTun
from hermsd.sim.world import MashSide, World, build_world

SHIPPED = (Path(__file__).parent.parent / "config" / "hermsd.yaml").read_text(encoding="utf-8")
PERIOD = 5.0


def edited(text: str, **values: str) -> str:
    """The shipped file with `key: value` lines replaced (first match of each key)."""
    for key, value in values.items():
        section, name = key.split("__") if "__" in key else ("", key)
        lines = text.split("\n")
        start = lines.index(f"{section}:") if section else 0
        index = next(i for i in range(start, len(lines)) if lines[i].startswith(f"  {name}:"))
        lines[index] = f"  {name}: {value}"
        text = "\n".join(lines)
    return text


BASE = edited(SHIPPED, output__backend="sim", log__dir="null")
HERMS = (
    edited(BASE, control__algorithm="type_a")
    + "mash_sensor:\n  kind: lm92\n  address: 0x49\npump:\n  backend: sim\n"
)
"""BASE with a HERMS's mash sensor and pump (for `start`'s `tun=doughed_in()`), on a PID law:
no heat is sent ahead of a pump start (predictive's prepared start, docs/herms.md "The pump
start"), so the pump runs at the period its command arrives, as these tests of the
commands' ways look for."""


def doughed_in() -> HermsTun:
    """A HERMS plant with its HLT at 20 °C, its mash just doughed in at 0 s: 50 L at 75 °C
    and 12 kg of grain at 20 °C, 70.1 °C; the pump off."""
    plant = HermsTun(FoptdPlant(start_c=20.0))
    plant.dough_in(grain_kg=12.0, grain_c=20.0, water_litres=50.0, water_c=75.0, t=0.0)
    return plant


class Events:
    """What the loop reported: period records, alarms, recorder writes, notifications."""

    def __init__(self) -> None:
        self.periods: list[PeriodRecord] = []
        self.alarms: list[Alarm] = []
        self.written: list[tuple[str, dict[str, Any]]] = []
        self.notified: list[str] = []

    def period(self, record: PeriodRecord) -> None:
        self.periods.append(record)

    def alarm(self, alarm: Alarm) -> None:
        self.alarms.append(alarm)

    def write(self, topic: str, log_time_ns: int, message: dict[str, Any]) -> None:
        self.written.append((topic, message))

    def logged(self) -> list[str]:
        return [m["message"] for topic, m in self.written if topic == "/hermsd/log"]

    def configs(self) -> list[dict[str, Any]]:
        return [m for topic, m in self.written if topic == "/hermsd/config"]


class FakeNotifier:
    """Stands in for sd_notify: records the protocol messages in order."""

    def __init__(self, log: list[str]) -> None:
        self._log = log

    def watchdog_interval(self) -> float | None:
        return None

    def ready(self) -> None:
        self._log.append("READY=1")

    def reloading(self) -> None:
        self._log.append("RELOADING=1")

    def status(self, text: str) -> None:
        self._log.append("STATUS=" + text)

    def stopping(self) -> None:
        self._log.append("STOPPING=1")

    def watchdog(self) -> None:
        self._log.append("WATCHDOG=1")


def start(
    tmp_path: Path,
    text: str = BASE,
    *,
    latches: LatchStore | None = None,
    watch: bool = True,
    reads: Start = at_once,
    saver: Saver | None = None,
    tun: Plant | None = None,
) -> tuple[Daemon, World, Path, Events]:
    """A started daemon on the simulated tun (or `tun`: a HERMS plant for the mash side)
    whose config is `text` in a file in `tmp_path`."""
    tmp_path.mkdir(parents=True, exist_ok=True)
    path = tmp_path / "hermsd.yaml"
    path.write_text(text, encoding="utf-8")
    source = ConfigFile(path, reads)
    config = source.load()
    clock = VirtualClock()
    world = build_world(config, clock, tun=tun)
    events = Events()
    mash = world.mash or MashSide()
    daemon = assemble(
        config,
        clock,
        world.sensor,
        world.outputs,
        mash_sensor=mash.mash_sensor,
        coil_sensor=mash.coil_sensor,
        current_sense=world.current,
        recorder=events,
        notifier=FakeNotifier(events.notified),  # type: ignore[arg-type]
        config_file=source if watch else None,
        latches=latches,
        saver=saver or Saver(threaded=False),  # a virtual clock: each save lands at once
    )
    daemon.listeners.append(events)
    daemon.start()
    return daemon, world, path, events


def write_in_place(path: Path, text: str) -> None:
    """As vim (with backupcopy) or nano save: truncate and write the same inode."""
    inode = path.stat().st_ino
    with path.open("r+", encoding="utf-8") as file:
        file.truncate(0)
        file.write(text)
    assert path.stat().st_ino == inode


def rename_over(path: Path, text: str) -> None:
    """As most editors save: write a new file beside it and rename it over the old one."""
    inode = path.stat().st_ino
    fresh = path.with_name(path.name + ".new")
    fresh.write_text(text, encoding="utf-8")
    os.replace(fresh, path)
    assert path.stat().st_ino != inode


def run_for(daemon: Daemon, seconds: float) -> None:
    daemon.run(until=daemon.clock.monotonic() + seconds)


@pytest.mark.parametrize("save", [write_in_place, rename_over])
def test_a_valid_edit_is_applied_within_one_period_and_logged(tmp_path: Path, save: Any) -> None:
    daemon, _world, path, events = start(tmp_path)
    run_for(daemon, 600.0)
    mark = len(events.periods)
    save(path, edited(BASE, control__setpoint="71.5"))
    run_for(daemon, PERIOD)
    after = events.periods[mark:]
    assert len(after) == 1 and after[0].setpoint == 71.5
    assert daemon.config.control.setpoint == 71.5
    reload = events.configs()[-1]
    assert reload["reason"] == "reload" and reload["t"] == after[0].t
    assert reload["config"]["control"]["setpoint"] == 71.5
    assert "config reloaded: control.setpoint changed" in events.logged()
    assert events.notified[-3:-1] == ["RELOADING=1", "READY=1"]


def test_an_unchanged_file_is_not_read_again(tmp_path: Path) -> None:
    daemon, _world, _path, events = start(tmp_path)
    run_for(daemon, 3600.0)
    assert [c["reason"] for c in events.configs()] == ["start"]
    assert "RELOADING=1" not in events.notified


def test_sighup_reads_the_file_even_when_it_looks_unchanged(tmp_path: Path) -> None:
    daemon, _world, _path, events = start(tmp_path)
    run_for(daemon, 60.0)
    daemon.request_reload()
    run_for(daemon, PERIOD)
    assert events.logged()[-1] == "config reloaded: nothing to change"
    assert events.notified.count("RELOADING=1") == 1


def outputs_after(events: Events, mark: int) -> list[tuple[float, float]]:
    return [(r.setpoint, r.output) for r in events.periods[mark:]]


@pytest.mark.parametrize(
    ("text", "where"),
    [
        (BASE.replace("control:\n", "control:\n  kc: [120\n", 1), ":"),
        (BASE.replace("  setpoint: 66.0", "  setpont: 70", 1), "control.setpont"),
        (edited(BASE, control__setpoint="500"), "control.setpoint"),
        (edited(BASE, control__ti="-800"), "control.ti"),
    ],
    ids=["bad-yaml", "unknown-key", "setpoint-500", "negative-ti"],
)
def test_an_invalid_edit_is_rejected_and_control_goes_on_unchanged(
    tmp_path: Path, text: str, where: str
) -> None:
    reference, _, _, reference_events = start(tmp_path / "reference")
    daemon, _world, path, events = start(tmp_path / "edited")
    for run in (reference, daemon):
        run_for(run, 1800.0)
    mark = len(events.periods)
    rename_over(path, text)
    for run in (reference, daemon):
        run_for(run, 1800.0)
    assert outputs_after(events, mark) == outputs_after(reference_events, mark)
    assert daemon.config == reference.config
    rejection = [m for m in events.logged() if m.startswith("config rejected")]
    assert len(rejection) == 1, "an invalid file is said once, not every period"
    assert f"{path}:" in rejection[0] and where in rejection[0]
    assert daemon.status_text().endswith("ok, config rejected (see journal)")
    # The next valid edit is taken, and the status clears.
    write_in_place(path, edited(BASE, control__setpoint="67.25"))
    run_for(daemon, PERIOD)
    assert daemon.setpoint == 67.25
    assert daemon.status_text().endswith(", ok")


def test_a_deleted_file_is_reported_and_a_new_one_picked_up(tmp_path: Path) -> None:
    daemon, _world, path, events = start(tmp_path)
    run_for(daemon, 60.0)
    path.unlink()
    run_for(daemon, PERIOD)
    assert "no such file" in events.logged()[-1]
    assert daemon.supervisor.heater_allowed
    path.write_text(edited(BASE, control__setpoint="64.0"), encoding="utf-8")
    run_for(daemon, PERIOD)
    assert daemon.setpoint == 64.0


def test_a_hardware_key_edit_is_refused_and_the_rest_applied(tmp_path: Path) -> None:
    daemon, _world, path, events = start(tmp_path)
    run_for(daemon, 60.0)
    rename_over(path, edited(BASE, sensor__address="0x49", control__setpoint="70.0"))
    run_for(daemon, PERIOD)
    assert daemon.config.sensor.address == 0x48
    assert daemon.setpoint == 70.0
    refusal = next(m for m in events.logged() if "need a restart" in m)
    assert "sensor.address" in refusal and "72" in refusal  # the address still in use, 0x48
    assert events.configs()[-1]["config"]["sensor"]["address"] == 0x48


def test_a_tuning_change_is_bumpless(tmp_path: Path) -> None:
    daemon, _world, path, events = start(tmp_path)
    run_for(daemon, 4 * 3600.0)  # holding 66 °C
    before = events.periods[-1]
    rename_over(path, edited(BASE, control__kc="40.0", control__ti="1600.0"))
    run_for(daemon, PERIOD)
    switched = events.periods[-1]
    assert switched.reset_from == before.output
    assert daemon.controller.params.kc == 40.0
    # The new controller starts from the output in force: what moves it in its first step
    # is its proportional action on the error's change in one period, never a jump.
    error_change = abs(switched.pv - before.pv) if switched.pv and before.pv else 0.0
    assert abs(switched.output - before.output) <= 40.0 * error_change + 0.1


def test_mode_and_manual_output_follow_the_file(tmp_path: Path) -> None:
    daemon, _world, path, events = start(tmp_path)
    run_for(daemon, 3600.0)
    rename_over(path, edited(BASE, control__mode="manual", control__manual_output="30.0"))
    run_for(daemon, PERIOD)
    assert (events.periods[-1].mode, events.periods[-1].output) == ("manual", 30.0)
    rename_over(path, edited(BASE, control__mode="auto", control__manual_output="30.0"))
    run_for(daemon, PERIOD)
    assert events.periods[-1].mode == "auto"
    assert events.periods[-1].reset_from == 30.0


def test_a_file_changing_while_it_is_read_is_read_again_later(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "hermsd.yaml"
    path.write_text(BASE, encoding="utf-8")
    source = ConfigFile(path, at_once)
    source.load()
    real_load = read.load_document

    def load_while_an_editor_writes(where: Any) -> read.Document:
        result = real_load(where)
        with path.open("a", encoding="utf-8") as file:
            file.write("\n")  # the editor's last write lands after our read
        return result

    path.write_text(edited(BASE, control__setpoint="60.0"), encoding="utf-8")
    monkeypatch.setattr("hermsd.config.file.load_document", load_while_an_editor_writes)
    assert source.poll() is None
    monkeypatch.setattr("hermsd.config.file.load_document", real_load)
    result = source.poll()
    assert isinstance(result, config_module.Config) and result.control.setpoint == 60.0
    assert source.poll() is None


@settings(
    max_examples=100,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(edits=mutated_config() | documents.map(lambda doc: yaml.safe_dump(doc).encode()))
def test_fuzz_a_running_daemon_survives_any_edit(tmp_path: Path, edits: bytes) -> None:
    """Whatever lands in the file, the loop runs on a config within every bound."""
    daemon, _world, path, events = start(tmp_path)
    run_for(daemon, 300.0)
    raw = edits.replace(b"backend: serial-rts", b"backend: sim").replace(
        b"dir: /var/log/hermsd", b"dir: null"
    )
    path.write_bytes(raw)
    run_for(daemon, 3 * PERIOD)
    assert_within_spec(daemon.config)
    assert events.periods[-1].t >= daemon.clock.monotonic() - PERIOD  # the loop goes on
    daemon.shutdown()


# -- a reload never applies an emptied or cut file ---------------------------------------------

# The brew: manual at 0 % under a low temperature limit. An emptied file taken as it
# is would put the tun in auto at 66 °C, full power, with the limit back at 95 °C.
CAREFUL = edited(BASE, control__mode="manual", control__setpoint="45.0", safety__max_temp="50.0")


@pytest.mark.parametrize(
    ("emptied", "why"),
    [
        ("", "names no section"),
        ("\n  \n", "names no section"),
        ("# hermsd\n# nothing here\n", "names no section"),
        ("{}\n", "names no section"),
        ("---\n", "the file must be a mapping of sections, got nothing"),
    ],
)
def test_an_emptied_file_is_rejected_and_nothing_changes(
    tmp_path: Path, emptied: str, why: str
) -> None:
    daemon, _world, path, events = start(tmp_path, CAREFUL)
    run_for(daemon, 600.0)
    running = daemon.config
    write_in_place(path, emptied)  # as `: > hermsd.yaml` does
    run_for(daemon, 600.0)
    assert daemon.config == running
    assert (daemon.mode, daemon.setpoint, daemon.config.safety.max_temp) == ("manual", 45.0, 50.0)
    assert all(record.output == 0.0 for record in events.periods)
    rejection = [m for m in events.logged() if m.startswith("config rejected")]
    assert len(rejection) == 1
    assert rejection[0].startswith(f"config rejected, still running on the last good one: {path}:")
    assert why in rejection[0]


def _cuts(text: str) -> list[str]:
    """The text cut after each line that sets a key, and inside each such line's value."""
    cuts = []
    end = 0
    for line in text.splitlines(keepends=True):
        end += len(line)
        if re.match(r"  [a-z_]+: \S", line):
            cuts += [text[:end], text[: end - 2]]  # whole lines kept; the value lost a character
    return cuts


# Values away from their defaults in every section, so a key a cut file lost would show.
RUNNING = edited(
    SHIPPED,
    tun__name="Kettle",
    tun__litres="60.0",
    control__setpoint="64.5",
    control__mode="manual",
    control__manual_output="20.0",
    control__kc="100.0",
    sensor__read_interval="2.0",
    output__min_on="0.1",
    contactor__channel="2",
    safety__max_temp="80.0",
    safety__reset="3",
    log__queue_size="5000",
)


def test_a_file_cut_short_anywhere_changes_no_running_value(tmp_path: Path) -> None:
    """A save cut short by a full disk is often valid YAML; it is never taken for an edit."""
    path = tmp_path / "hermsd.yaml"
    path.write_text(RUNNING, encoding="utf-8")
    source = ConfigFile(path, at_once)
    running = source.load()
    taken = 0
    cuts = _cuts(RUNNING)
    assert len(cuts) > 100
    for cut in cuts:
        path.write_text(cut, encoding="utf-8")
        result = source.poll(force=True)
        if isinstance(result, config_module.Config):
            assert result == running, f"a file cut after {cut[-40:]!r} was taken"
            taken += 1
        else:
            assert isinstance(result, config_module.ConfigError)
    assert taken == 1  # only the cut after the last line, which is the whole file


def test_a_key_taken_out_is_refused_until_it_is_written_with_its_default(tmp_path: Path) -> None:
    daemon, _world, path, events = start(tmp_path, CAREFUL)
    run_for(daemon, 60.0)
    rename_over(path, CAREFUL.replace("  mode: manual\n", ""))
    run_for(daemon, PERIOD)
    assert daemon.mode == "manual"
    assert events.logged()[-1] == (
        f"config rejected, still running on the last good one: {path}: control.mode is no "
        "longer in the file, as in a save cut short (a reload keeps every key of the running "
        "file: to return one to its default, write the default value; a restart takes the "
        "file as it is)"
    )
    rename_over(path, CAREFUL.replace("  mode: manual\n", "  mode: auto\n"))
    run_for(daemon, PERIOD)
    assert daemon.mode == "auto"


def test_a_section_taken_out_is_named_once(tmp_path: Path) -> None:
    daemon, _world, path, events = start(tmp_path)
    run_for(daemon, 60.0)
    log_section, next_section = BASE.index("\nlog:\n"), BASE.index("\nalerts:\n")
    rename_over(path, BASE[: log_section + 1] + BASE[next_section + 1 :])
    run_for(daemon, PERIOD)
    assert f"{path}: log is no longer in the file" in events.logged()[-1]


def test_a_last_line_without_its_line_break_is_refused(tmp_path: Path) -> None:
    text = "output:\n  backend: sim\nlog:\n  dir: null\ncontrol:\n  setpoint: 60.0\n"
    daemon, _world, path, events = start(tmp_path, text)
    run_for(daemon, 60.0)
    rename_over(path, text[: text.index("0.0")])  # `setpoint: 6`, the rest not yet saved
    run_for(daemon, PERIOD)
    assert daemon.setpoint == 60.0
    assert f"{path}:6:1: the last line has no line break" in events.logged()[-1]


# -- the disk is read off the loop, and bounded ------------------------------------------------


class SlowDisk:
    """A reader that finishes its checks only when the test says so."""

    def __init__(self) -> None:
        self.reads: list[
            tuple[Check, Future[config_module.Config | config_module.ConfigError | None]]
        ] = []

    def __call__(
        self, check: Check
    ) -> Future[config_module.Config | config_module.ConfigError | None]:
        future: Future[config_module.Config | config_module.ConfigError | None] = Future()
        self.reads.append((check, future))
        return future

    def finish(self) -> None:
        for check, future in self.reads:
            if not future.done():
                future.set_result(check())


def test_the_loop_never_waits_for_the_disk(tmp_path: Path) -> None:
    disk = SlowDisk()
    daemon, _world, path, events = start(tmp_path, reads=disk)
    run_for(daemon, 60.0)
    rename_over(path, edited(BASE, control__setpoint="70.0"))
    mark = len(events.periods)
    run_for(daemon, 20 * PERIOD)  # the read hangs all along
    times = [record.t for record in events.periods[mark:]]
    assert len(times) == 20 and all(b - a == PERIOD for a, b in itertools.pairwise(times))
    assert daemon.setpoint == 66.0
    assert len(disk.reads) == 1, "one read at a time, however long it takes"
    disk.finish()
    run_for(daemon, PERIOD)  # taken at the next period boundary
    assert daemon.setpoint == 70.0


def test_the_reader_thread_is_not_the_callers() -> None:
    release = threading.Event()
    ran_on: list[str] = []

    def check() -> None:
        ran_on.append(threading.current_thread().name)
        release.wait(timeout=30)

    future = in_thread(check)
    assert not future.done()  # it cannot finish before it is released
    release.set()
    assert future.result(timeout=30) is None
    assert ran_on == ["hermsd-config"]


def test_a_huge_file_is_refused_without_reading_it(tmp_path: Path) -> None:
    daemon, _world, path, events = start(tmp_path)
    run_for(daemon, 60.0)
    os.truncate(path, 50_000_000)  # sparse: 50 MB that cost no disk
    run_for(daemon, PERIOD)
    assert events.logged()[-1] == (
        f"config rejected, still running on the last good one: {path}: is 50000000 bytes "
        "long, more than the 64 KiB a config file may be (the shipped one is under 16 KiB: "
        "is this the right file?)"
    )
