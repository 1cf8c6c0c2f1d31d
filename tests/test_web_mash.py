"""`hermsd web` of a HERMS over HTTP against a simulated daemon: the mash's reading in each
pushed period and in the chart's history, the pump's state, and the pump started and stopped
through the page's command address with a login; refused in the daemon's words with no pump.

The plant is `test_reload.doughed_in()`: its mash mixed at 70.1 °C (50 L at 75 °C and 12 kg of
grain at 20 °C: (50·4186·75 + 12·1700·20) / (50·4186 + 12·1700) J/K), the HLT at 20 °C."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from test_reload import HERMS, doughed_in
from webpage import PASSWORD, TIMEOUT, Site, site

MIXED_C = (50 * 4186 * 75 + 12 * 1700 * 20) / (50 * 4186 + 12 * 1700)  # 70.115 °C
MASH_FLOOR = 20.0  # °C: the room's, which the mash (its pump off) only cools towards, however
# long the virtual clock ran before the first look (that depends on the machine's load)
NO_PUMP = (
    "refused, nothing changed: pump: no pump is fitted (set pump.backend in the config file "
    "and restart hermsd)"
)


@pytest.fixture(scope="module")
def herms(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Site]:
    with site(tmp_path_factory.mktemp("herms"), text=HERMS, tun=doughed_in()) as served:
        yield served


def _client(live: Site) -> httpx.Client:
    return httpx.Client(base_url=live.url, timeout=TIMEOUT)


def _events(client: httpx.Client, count: int) -> list[dict[str, Any]]:
    events: list[dict[str, Any]] = []
    with client.stream("GET", "/api/events") as stream:
        for line in stream.iter_lines():
            if line.startswith("data: "):
                events.append(json.loads(line[len("data: ") :]))
            if len(events) == count:
                return events
    raise AssertionError("the event stream ended")


def _logged_in(client: httpx.Client) -> dict[str, str]:
    reply = client.post("/api/login", json={"password": PASSWORD})
    assert reply.status_code == 200
    return {"x-csrf-token": reply.json()["csrf"]}


def test_each_period_pushes_the_mash_and_the_pump_and_the_history_has_the_mash(
    herms: Site,
) -> None:
    with _client(herms) as client:
        *_, pushed = _events(client, 3)
        history = client.get("/api/history").json()
    status = pushed["status"]
    # the LM92's reading of the mash, below the mix as the lidded tun loses heat to the room
    # (10 W/K of 230 kJ/K: 50 K × (1 − e^(−3600/22970)) = 7.3 °C in an hour), above the room
    assert status["mash"]["fault"] is None
    assert MASH_FLOOR < status["mash"]["celsius"] <= MIXED_C
    assert status["pump"] is False
    shown = [status["t"], status["pv"], status["setpoint"], status["output"]]
    # the rows are rounded to 0.001 (api/history.py): 62.9375 °C is 62.938 there
    shown += [status["mash"]["celsius"], status["mash"]["hlt_setpoint"]]
    assert pushed["rows"][-1] == [round(v, 3) for v in shown]
    # one mash value a period beside the HLT's, the newest a good reading of the mash, and
    # the HLT's setpoint the outer loop chose: never above the mash's + max_hlt_above_mash
    assert len(history["mash"]) == len(history["hlt_setpoint"]) == len(history["t"]) >= 3
    assert MASH_FLOOR < history["mash"][-1] <= MIXED_C
    assert all(aim <= 66.0 + 10.0 for aim in history["hlt_setpoint"])
    assert history["pv"][-1] < 60.0  # the HLT heats from 20 °C: two lines apart


def test_the_pump_is_started_and_stopped_with_a_login(herms: Site) -> None:
    with _client(herms) as client:
        refused = client.post("/api/command", json={"cmd": "set", "pump": True})
        assert refused.status_code == 401
        assert herms.daemon.mash_side_fields()["pump"] is False
        headers = _logged_in(client)
        on = client.post("/api/command", json={"cmd": "set", "pump": True}, headers=headers)
        assert on.status_code == 200, on.text
        assert on.json()["status"]["pump"] is True
        assert herms.daemon.mash_side_fields()["pump"] is True
        off = client.post("/api/command", json={"cmd": "set", "pump": False}, headers=headers)
    assert off.status_code == 200 and off.json()["status"]["pump"] is False
    assert herms.daemon.mash_side_fields()["pump"] is False
    said = herms.events.logged()
    assert "pump on: by the operator (from the control socket)" in said
    assert "pump off: by the operator (from the control socket)" in said


@pytest.mark.parametrize(
    ("command", "says"),
    [
        ({"cmd": "set", "pump": "on"}, 'pump: expected true or false, got "on"'),
        ({"cmd": "set", "pump": True, "setpoint": 60}, "set pump"),
    ],
)
def test_a_bad_pump_command_is_one_line_and_changes_nothing(
    herms: Site, command: dict[str, object], says: str
) -> None:
    pump = herms.daemon.mash_side_fields()["pump"]
    with _client(herms) as client:
        reply = client.post("/api/command", json=command, headers=_logged_in(client))
    assert reply.status_code == 400 and says in reply.json()["error"]
    assert "\n" not in reply.json()["error"]
    assert herms.daemon.mash_side_fields()["pump"] is pump


def test_without_a_mash_side_nothing_of_it_is_pushed_and_the_pump_is_refused(
    tmp_path: Path,
) -> None:
    with site(tmp_path) as hlt_only, _client(hlt_only) as client:
        *_, pushed = _events(client, 2)
        history = client.get("/api/history").json()
        reply = client.post(
            "/api/command", json={"cmd": "set", "pump": True}, headers=_logged_in(client)
        )
    assert (pushed["status"]["mash"], pushed["status"]["pump"]) == (None, None)
    assert set(history["mash"]) == set(history["hlt_setpoint"]) == {None}
    assert reply.status_code == 422 and reply.json()["error"] == NO_PUMP
    assert hlt_only.daemon.mash_side_fields()["pump"] is None
