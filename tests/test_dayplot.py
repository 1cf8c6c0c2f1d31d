"""`hermsd replay --plot`: what is marked on the day's picture, and that no label hides another.

The log here is written by hand: an hour of 5 s periods with a mash program (events on
/hermsd/program as the program runner writes them), an edit of the setpoint after it, a
spell of manual power, a sensor fault and cold water poured in. Every expected time below
follows from how the log is built.
"""

from __future__ import annotations

import dataclasses
import itertools
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from matplotlib.colors import to_rgb
from matplotlib.figure import Figure
from matplotlib.text import Text
from matplotlib.transforms import Bbox

from hermsd.config import read
from hermsd.config import schema as config_module
from hermsd.log import dayplot, reader, topics
from hermsd.log.dayplot import Marker, rows
from hermsd.log.recorder import Recorder
from hermsd.log.topics import CONFIG_TOPIC, LOG_TOPIC, PERIOD_TOPIC, LogLevel, log_message
from hermsd.runtime.period import PeriodRecord
from hermsd.sim.clock import DEFAULT_EPOCH_NS, VirtualClock

S = 1_000_000_000
PERIOD = 5.0
T0 = 1000.0  # the daemon's monotonic time at the first period


@pytest.fixture
def berlin(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """Local time in Berlin (UTC+1 in January) for the test, and the zone restored after."""
    monkeypatch.setenv("TZ", "Europe/Berlin")
    time.tzset()
    yield
    monkeypatch.undo()
    time.tzset()


def program_event(t: float, event: str, **fields: Any) -> dict[str, Any]:
    record = {"t": t, "event": event, "program": "Step mash", "step": None, "name": None}
    return {**record, "setpoint": None, "message": None, **fields}


def brew_hour(directory: Path, monkeypatch: pytest.MonkeyPatch) -> list[Path]:
    """An hour from the epoch (00:00 UTC): the program runs 600..3000 s (Strike at 72 °C,
    reached at 900 s, waiting for "Mash in" 1000..1300 s, then Saccharification at 66 °C);
    manual 40 % 2000..2100 s; sensor_fault in the records of 2500..2525 s (told at 2498 s);
    the setpoint edited to 70 °C at 3300 s; PV falls 3 °C at 3400 s (water)."""
    config = read.to_dict(config_module.DEFAULT)
    config["tun"]["name"] = "Kettle 2"
    messages: list[tuple[str, float, dict[str, Any]]] = [
        (CONFIG_TOPIC, 0.0, {"t": T0, "config": config, "reason": "start"})
    ]
    for k in range(720):
        at = k * PERIOD
        setpoint = 72.0 if 600 <= at < 1300 else 66.0 if at < 3300 else 70.0
        pv = 60.0 if at < 3400 else 57.0
        manual = 2000 <= at < 2100
        alarm = ["sensor_fault"] if 2500 <= at < 2530 else []
        record = PeriodRecord(
            t=T0 + at, k=k + 1, setpoint=setpoint, pv=None if alarm else pv,
            readings=[], output=40.0 if manual else 20.0, applied=20.0, p=0.0, i=0.0, d=0.0,
            mode="manual" if manual else "auto", algorithm="pid",
            state="manual" if manual else "alarm" if alarm else "ok", alarms=alarm,
            heater_allowed=not alarm,
        )  # fmt: skip
        messages.append((PERIOD_TOPIC, at, dataclasses.asdict(record)))
    fault = "fault sensor_fault: 2 bad reads in a row: no answer; heater off"
    messages.append((LOG_TOPIC, 2498.0, log_message(LogLevel.WARNING, fault, 0)))
    program = [
        (600, "started", {}),
        (600, "step_started", {"step": 0, "name": "Strike", "setpoint": 72.0}),
        (900, "step_reached", {"step": 0, "name": "Strike", "setpoint": 72.0}),
        (1000, "step_done", {"step": 0, "name": "Strike", "setpoint": 72.0}),
        (1000, "waiting", {"step": 0, "name": "Strike", "message": "Mash in"}),
        (1300, "confirmed", {"step": 0, "name": "Strike"}),
        (1300, "step_started", {"step": 1, "name": "Saccharification", "setpoint": 66.0}),
        (3000, "finished", {}),
    ]
    for at, event, fields in program:
        messages.append((topics.PROGRAM_TOPIC, at, program_event(T0 + at, event, **fields)))
    directory.mkdir(exist_ok=True)
    writer = Recorder(directory, now=VirtualClock().monotonic, lossless=True)
    for topic, wall_s, message in sorted(messages, key=lambda m: m[1]):
        writer.write(topic, DEFAULT_EPOCH_NS + round(wall_s * S), message)
    writer.close()
    return sorted(directory.glob("*.mcap"))


@pytest.fixture
def hour(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> reader.Log:
    return reader.load(brew_hour(tmp_path / "log", monkeypatch))


def test_program_events_are_read_on_the_replay_clock(hour: reader.Log) -> None:
    assert [(e.at, e.event) for e in hour.program][:3] == [
        (600.0, "started"), (600.0, "step_started"), (900.0, "step_reached")
    ]  # fmt: skip
    waiting = hour.program[4]
    assert (waiting.name, waiting.message, waiting.setpoint) == ("Strike", "Mash in", None)


def test_every_event_of_the_day_is_marked(hour: reader.Log) -> None:
    assert dayplot.markers(hour) == [
        Marker(600.0, "program", "program Step mash"),
        Marker(600.0, "program", "Strike 72 °C"),
        Marker(1000.0, "program", "waiting: Mash in"),
        Marker(1300.0, "program", "confirmed"),
        Marker(1300.0, "program", "Saccharification 66 °C"),
        Marker(2000.0, "mode", "manual 40 %"),
        Marker(2100.0, "mode", "auto"),
        # raised at 2498 s by its event; the records hold it 2500..2525 s, cleared at 2530 s
        Marker(2498.0, "alarm", "sensor_fault 32 s"),
        Marker(3000.0, "program", "program done"),
        # the program's setpoint changes (600, 1300 s) are its steps, not edits
        Marker(3300.0, "edit", "setpoint 70 °C"),
        Marker(3395.0, "water", "water added? PV −3 °C"),  # the last period before the fall
    ]


def test_an_alarm_still_active_at_the_end_is_shaded_to_the_end(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    log = reader.load(brew_hour(tmp_path / "log", monkeypatch))
    log.periods[-1] = dataclasses.replace(log.periods[-1], alarms=["ssr_stuck_on"])
    assert dayplot.alarm_spans(log)[-1] == dayplot.Span("ssr_stuck_on", 3595.0, 3595.0, True)
    assert dayplot.markers(log)[-1].text == "ssr_stuck_on still at the end"


def test_rows_keep_labels_apart_in_as_few_rows_as_possible() -> None:
    # by hand: (0,10) row 0; (5,15) overlaps it: row 1; (12,20) is clear of row 0's end
    # 10 by 2 ≥ the gap 1: row 0; (16,30): row 0 ends at 20, row 1 at 15 (+1 = 16): row 1
    assert rows([(0, 10), (5, 15), (12, 20), (16, 30)], 1.0) == [0, 1, 0, 1]
    assert rows([(5, 15), (0, 10)], 1.0) == [1, 0]  # taken by left edge, whatever the order
    assert rows([(0, 10), (10.5, 20)], 1.0) == [0, 1]  # closer than the gap
    assert rows([(i, i + 100.0) for i in range(5)], 1.0) == [0, 1, 2, 3, 4]
    assert rows([], 1.0) == []


def boxes(figure: Figure) -> tuple[list[Text], list[Bbox]]:
    """The event labels and the extents of their boxes, in pixels, as drawn."""
    figure.canvas.draw()
    labels = [t for t in figure.findobj(Text) if t.get_gid() == "event-label"]
    extents = []
    for label in labels:
        patch = label.get_bbox_patch()
        assert patch is not None
        extents.append(patch.get_window_extent())
    return labels, extents


def assert_apart(figure: Figure) -> list[Text]:
    """No label's box overlaps another's, the title or a legend; each is inside the strip."""
    labels, extents = boxes(figure)
    for (a, box_a), (b, box_b) in itertools.combinations(zip(labels, extents, strict=True), 2):
        assert not box_a.overlaps(box_b), (a.get_text(), b.get_text())
    renderer = figure.canvas.get_renderer()  # type: ignore[attr-defined]
    strip = figure.axes[0].get_window_extent(renderer)
    others = [figure._suptitle]  # type: ignore[attr-defined]
    others += [t for axes in figure.axes if axes.get_legend() for t in axes.get_legend().texts]
    for label, box in zip(labels, extents, strict=True):
        assert strip.x0 <= box.x0 and box.x1 <= strip.x1, label.get_text()
        assert strip.y0 <= box.y0 and box.y1 <= strip.y1, label.get_text()
        for other in others:
            assert not box.overlaps(other.get_window_extent(renderer)), label.get_text()
    return labels


def test_no_label_overlaps_another(hour: reader.Log, berlin: None) -> None:
    figure = dayplot.draw(hour)
    labels = assert_apart(figure)
    assert sorted(t.get_text() for t in labels) == sorted(m.text for m in dayplot.markers(hour))
    # 600 s holds two labels, 1300 s two more: they cannot share a row
    assert len({round(t.get_position()[1], 6) for t in labels}) >= 2


def test_crowded_labels_take_more_rows_and_still_do_not_overlap(hour: reader.Log) -> None:
    for i in range(12):  # a burst of mode changes, one a period apart
        at = 1500.0 + PERIOD * i
        k = round(at / PERIOD)
        hour.periods[k] = dataclasses.replace(
            hour.periods[k], mode="manual" if i % 2 == 0 else "auto", output=10.0 + i
        )
    figure = dayplot.draw(hour)
    labels = assert_apart(figure)
    assert len({round(t.get_position()[1], 6) for t in labels}) >= 6


def test_title_axis_and_panels_say_what_a_brewer_needs(hour: reader.Log, berlin: None) -> None:
    figure = dayplot.draw(hour)
    strip, temps, error, power = figure.axes
    title = figure._suptitle.get_text()  # type: ignore[attr-defined]
    # the epoch is 00:00 UTC on 1 January 2026: 01:00 in Berlin; the last period 00:59:55 UTC
    assert title == "Kettle 2 · Thursday 1 January 2026, 01:00–01:59 · program Step mash"
    assert power.get_xlabel() == "local time (CET, UTC+01:00)"
    assert [t.get_text() for t in power.get_xticklabels()][:2] == ["01:00", "01:05"]
    assert error.get_ylim() == (-3.0, 3.0)
    [band] = [p for p in error.patches if p.get_label() == "±0.5 °C band"]
    corners = error.transData.inverted().transform(
        band.get_transform().transform(band.get_path().vertices)
    )
    assert sorted({round(y, 6) for _, y in corners}) == [-0.5, 0.5]
    [applied] = [c for c in power.collections if c.get_label() == "applied (SSR duty)"]
    [output] = [line for line in power.lines if line.get_label() == "output"]
    assert to_rgb(applied.get_facecolor()[0]) != to_rgb(output.get_color())
    for axes in (strip, temps, error, power):  # the alarm shaded in every panel
        assert to_rgb(dayplot.COLOURS["alarm"]) in [to_rgb(p.get_facecolor()) for p in axes.patches]


def test_labels_beyond_the_rows_allowed_are_counted_not_crammed(hour: reader.Log) -> None:
    for i in range(40):
        k = round(1500.0 / PERIOD) + i
        hour.periods[k] = dataclasses.replace(
            hour.periods[k], mode="manual" if i % 2 == 0 else "auto", output=10.0 + i
        )
    figure = dayplot.draw(hour)
    labels = assert_apart(figure)
    assert len({round(t.get_position()[1], 6) for t in labels}) == dayplot.MAX_ROWS
    missing = len(dayplot.markers(hour)) - len(labels)
    assert missing > 0
    assert figure.axes[0].get_ylabel() == f"events\n({missing} lines\nnot labelled)"
