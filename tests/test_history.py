"""The daemon's history ring and the `history` command that pages through it."""

from __future__ import annotations

import itertools
import json
import time
from pathlib import Path

import pytest
from test_control import TIMEOUT, connect, exchange, served
from test_replay import period

from hermsd.api.history import HistoryRing, capacity_for, encode_row
from hermsd.runtime.period import PeriodRecord


def _ring(times: list[float], capacity: int) -> HistoryRing:
    ring = HistoryRing(capacity)
    for t in times:
        ring.append(t, str(t).encode())
    return ring


def _times(rows: list[bytes]) -> list[float]:
    return [float(row) for row in rows]


def test_a_day_at_five_seconds_is_17280_rows() -> None:
    assert capacity_for(5.0) == 24 * 3600 // 5 == 17280
    assert capacity_for(7.0) == 12343  # 86400 / 7 = 12342.9: the last part-period kept too


def _record(**values: object) -> PeriodRecord:
    """A period of t 12345 s, PV 65.9375 °C, setpoint 66, output 12.3456789 %, applied 12.3 %."""
    fields = {"t": 12345.0, "pv": 65.9375, "applied": 12.3, **values}
    record = period(1, fields.pop("t"), fields.pop("pv"), fields.pop("applied"))  # type: ignore[arg-type]
    return PeriodRecord(**{**record, "setpoint": 66.0, "output": 12.3456789, **fields})


@pytest.mark.parametrize(
    ("values", "row"),
    [
        ({}, b"[12345.0,65.938,66.0,12.346,12.3,null,null]"),  # 65.9375: half to even
        ({"pv": None, "t": 0.0004}, b"[0.0,null,66.0,12.346,12.3,null,null]"),
        ({"output": float("nan"), "applied": 100}, b"[12345.0,65.938,66.0,null,100,null,null]"),
        ({"mash": 64.8125}, b"[12345.0,65.938,66.0,12.346,12.3,64.812,null]"),
        (
            {"mash": 64.8125, "hlt_setpoint": 71.4004},
            b"[12345.0,65.938,66.0,12.346,12.3,64.812,71.4]",
        ),
    ],
)
def test_a_row_is_the_periods_numbers_rounded_to_a_thousandth(
    values: dict[str, object], row: bytes
) -> None:
    assert encode_row(_record(**values))[1] == row


def test_the_ring_keeps_the_newest_rows_in_order_once_full() -> None:
    ring = _ring([5.0 * k for k in range(1, 11)], capacity=4)  # 5 .. 50, room for four
    rows, more = ring.page(None, 100)
    assert _times(rows) == [35.0, 40.0, 45.0, 50.0]
    assert not more


@pytest.mark.parametrize(
    ("since", "limit", "expected", "more"),
    [
        (None, 2, [35.0, 40.0], True),
        (40.0, 100, [45.0, 50.0], False),  # strictly after `since`
        (41.0, 1, [45.0], True),
        (50.0, 100, [], False),
        (0.0, 100, [35.0, 40.0, 45.0, 50.0], False),  # older than the oldest kept: all
    ],
)
def test_a_page_is_the_rows_after_since(
    since: float | None, limit: int, expected: list[float], more: bool
) -> None:
    ring = _ring([5.0 * k for k in range(1, 11)], capacity=4)
    rows, more_ = ring.page(since, limit)
    assert (_times(rows), more_) == (expected, more)


def test_paging_with_the_last_t_reads_every_row_once_across_the_wrap() -> None:
    ring = _ring([float(k) for k in range(1, 1001)], capacity=300)
    seen: list[float] = []
    since: float | None = None
    more = True
    while more:
        rows, more = ring.page(since, 7)
        seen += _times(rows)
        since = seen[-1]
    assert seen == [float(k) for k in range(701, 1001)]


def test_the_socket_pages_through_the_periods_the_loop_ran(tmp_path: Path) -> None:
    with served(tmp_path) as (daemon, where):
        deadline = time.monotonic() + TIMEOUT
        while daemon.clock.monotonic() < 200.0 and time.monotonic() < deadline:
            time.sleep(0.01)
        with connect(where) as sock:
            first = exchange(sock, b'{"v": 1, "cmd": "history", "limit": 10}\n')
            rest = exchange(
                sock,
                json.dumps({"v": 1, "cmd": "history", "since": first["rows"][-1][0]}).encode()
                + b"\n",
            )
            status = exchange(sock, b'{"v": 1, "cmd": "status"}\n')
    assert first["ok"] and first["more"] and first["period"] == 5.0
    assert first["fields"] == [
        "t",
        "pv",
        "setpoint",
        "output",
        "applied",
        "mash",
        "hlt_setpoint",
    ]
    rows = first["rows"] + rest["rows"]
    times = [row[0] for row in rows]
    # One row a period, 5 s apart, none lost or repeated between the pages.
    assert len(rows) >= 40
    assert all(b - a == pytest.approx(5.0) for a, b in itertools.pairwise(times))
    assert rows[0][2] == 66.0  # the shipped setpoint
    # Rows come no later than the status the loop published (the loop runs on meanwhile).
    assert status["t"] >= times[-1]
