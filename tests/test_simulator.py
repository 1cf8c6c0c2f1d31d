"""The simulator as a user drives it: any tun (built in, described, or from outside), the boil,
the open lid, and state kept from one simulated day to the next.

Expected figures come from steam tables, closed forms and energy balances written out here.
"""

from __future__ import annotations

import errno
import json
import math
import os
import tempfile
from pathlib import Path

import pytest

from hermsd.cli import commands as cli
from hermsd.runtime.daemon import Daemon
from hermsd.runtime.period import PeriodRecord
from hermsd.safety.limits import Alarm
from hermsd.sim import scenario
from hermsd.sim.hlt import (
    BOILING_C,
    EVAPORATION_W_PER_M2_KPA,
    ROOM_RELATIVE_HUMIDITY,
    WATER_J_PER_LITRE_K,
    PhysicalPlant,
    evaporation_w,
    pot_surface_m2,
    saturation_kpa,
)
from hermsd.sim.tuns import FAMILY

# Saturation pressure of water, kPa (IAPWS-IF97 steam tables).
STEAM_TABLE_KPA = {20.0: 2.3393, 66.0: 26.163, 80.0: 47.416, 100.0: 101.42}


# --------------------------------------------------------------------------- the boil


@pytest.mark.parametrize("model", ["foptd", "physical"])
def test_a_shorted_ssr_without_a_contactor_stops_the_water_at_its_boiling_point(
    model: str,
) -> None:
    """Full power for hours would carry the water to T_amb + P/UA ≈ 189 °C; it boils at 100."""
    shorted = scenario.parse_scenario(
        {
            "duration": "5h",
            "setpoint": 66,
            "plant": {"model": model},
            "events": [{"at": "2h", "ssr": "stuck_on"}],
        }
    )
    result = scenario.run(shorted)
    # The sensor (noiseless, lagging on the physical tun) closes in on the boiling water.
    assert max(s.temp for s in result.samples) <= BOILING_C
    assert result.samples[-1].temp > BOILING_C - 1e-3
    assert "ssr_stuck_on" in [alarm["kind"] for alarm in result.summary["alarms"]]


# ----------------------------------------------------------------------- evaporation


def test_saturation_pressure_matches_the_steam_tables() -> None:
    for temp_c, kpa in STEAM_TABLE_KPA.items():
        assert saturation_kpa(temp_c) == pytest.approx(kpa, rel=5e-3)


def test_an_open_40_cm_pot_at_66_c_loses_what_the_correlation_gives_by_hand() -> None:
    """50 L in a pot as tall as wide: r = (0.05/2π)^⅓ = 0.1996 m, A = 0.1252 m² (a 40 cm
    pot). At 66 °C in a 20 °C room at 50 % humidity: Δp = 26.163 − 0.5·2.3393 = 24.99 kPa,
    E = 89 W/(m²·kPa) · 0.1252 m² · 24.99 kPa = 278.5 W."""
    assert pot_surface_m2(50.0) == pytest.approx(0.12522, rel=1e-4)
    assert EVAPORATION_W_PER_M2_KPA == 89.0
    assert ROOM_RELATIVE_HUMIDITY == 0.5
    assert evaporation_w(66.0, 20.0, pot_surface_m2(50.0)) == pytest.approx(278.5, rel=4e-3)
    # It grows steeply with temperature: ×1.85 from 66 to 80 °C, ×4 to the boil.
    ratio = (47.416 - 1.1697) / (26.163 - 1.1697)
    assert evaporation_w(80.0, 20.0, 0.1252) / evaporation_w(66.0, 20.0, 0.1252) == (
        pytest.approx(ratio, rel=4e-3)
    )


def open_pot(**params: float) -> PhysicalPlant:
    return PhysicalPlant(
        litres=50.0, ua_w_per_k=6.0, lid=False, start_c=66.0, ambient_c=20.0, **params
    )


def test_the_open_pot_cools_at_the_rate_its_losses_give() -> None:
    """Heater off at 66 °C: C·dT/dt = −UA·(66 − 20) − 278.5 W, C = 50 L · 4186 J/(L·K)."""
    plant = open_pot(sensor_lag_s=0.0)
    rate = -(6.0 * 46.0 + 278.5) / (50.0 * WATER_J_PER_LITRE_K)
    assert plant.water_temperature(1.0) - 66.0 == pytest.approx(rate, rel=5e-3)
    lidded = PhysicalPlant(litres=50.0, ua_w_per_k=6.0, start_c=66.0, sensor_lag_s=0.0)
    assert lidded.water_temperature(1.0) - 66.0 == pytest.approx(
        -(6.0 * 46.0) / (50.0 * WATER_J_PER_LITRE_K), rel=1e-4
    )


def runge_kutta_open_pot(power_w: float, end: float, step: float = 0.5) -> float:
    """The nonlinear equation C·dT/dt = P − UA·(T − T_amb) − E(T), integrated finely (RK4)."""
    capacity = 50.0 * WATER_J_PER_LITRE_K
    area = pot_surface_m2(50.0)

    def slope(temp: float) -> float:
        return (power_w - 6.0 * (temp - 20.0) - evaporation_w(temp, 20.0, area)) / capacity

    temp, t = 66.0, 0.0
    while t < end - 1e-9:
        k1 = slope(temp)
        k2 = slope(temp + step / 2 * k1)
        k3 = slope(temp + step / 2 * k2)
        k4 = slope(temp + step * k3)
        temp += step / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        t += step
    return temp


@pytest.mark.parametrize("power_w", [0.0, 3500.0])
def test_the_tangent_model_follows_the_nonlinear_equation(power_w: float) -> None:
    """Two hours cooling, or half an hour heating from 66 to 89 °C: within 2e-5 °C."""
    plant = open_pot(transport_delay_s=0.0, sensor_lag_s=0.0, element_watts=power_w or 1.0)
    plant.set_heater(power_w > 0.0, 0.0)
    end = 1800.0 if power_w else 7200.0
    assert plant.water_temperature(end) == pytest.approx(
        runge_kutta_open_pot(power_w, end), abs=2e-5
    )


def test_the_open_pot_does_not_depend_on_how_often_anyone_looks() -> None:
    often, seldom = open_pot(), open_pot()
    for plant in (often, seldom):
        plant.set_heater(True, 0.0)
    for t in range(1, 3600):
        if t == 1235:
            for plant in (often, seldom):
                plant.set_heater(False, 1234.5)
        often.temperature(float(t))
    assert often.temperature(3600.0) == pytest.approx(seldom.temperature(3600.0), abs=1e-10)
    assert often.energy_lost(3600.0) == pytest.approx(seldom.energy_lost(3600.0), rel=1e-10)


def test_the_open_pot_books_close_at_the_boil() -> None:
    """Heat in = change of the water's enthalpy + lost (walls, evaporation) + boiled."""
    plant = open_pot(element_watts=5000.0)
    plant.set_heater(True, 0.0)
    end = 3 * 3600.0
    assert plant.water_temperature(end) == BOILING_C
    stored = 50.0 * WATER_J_PER_LITRE_K * (BOILING_C - 66.0)
    heat_in = plant.energy_in(end)
    booked = stored + plant.energy_lost(end) + plant.energy_boiled(end)
    assert booked == pytest.approx(heat_in, rel=1e-9)
    # At the boil the losses are UA·80 K + E(100 °C) and the rest boils off.
    boil_loss = 6.0 * 80.0 + evaporation_w(BOILING_C, 20.0, pot_surface_m2(50.0))
    before = plant.energy_boiled(end)
    assert plant.energy_boiled(end + 100.0) - before == pytest.approx(
        (5000.0 - boil_loss) * 100.0, rel=1e-3
    )


# ------------------------------------------------------------- the plant: mapping


@pytest.mark.parametrize(
    ("plant", "where"),
    [
        ({"model": "kettle"}, "plant.model: expected one of foptd, physical"),
        ({"model": "physical", "litre": 50}, "plant.litre: unknown key for model physical"),
        ({"model": "foptd", "lid": False}, "plant.lid: unknown key for model foptd"),
        ({"model": "physical", "litres": "lots"}, "plant.litres: expected a number"),
        ({"model": "physical", "lid": "maybe"}, "plant.lid: expected on or off"),
        ({"model": "physical", "litres": -3}, "plant.litres: litres = -3 is invalid"),
        ({"model": "physical", "noise_c": -0.1}, "plant.noise_c: noise_c = -0.1 is invalid"),
        ({"model": "physical", "seed": 1.5}, "plant.seed: expected a whole number"),
        ([1, 2], "plant: expected a mapping"),
    ],
)
def test_a_bad_plant_mapping_names_its_key(plant: object, where: str) -> None:
    with pytest.raises(scenario.ScenarioError, match=f"^tun.yaml: {where}"):
        scenario.parse_scenario({"plant": plant}, "tun.yaml")


def test_lid_off_in_yaml_reads_as_an_open_pot(tmp_path: Path) -> None:
    path = tmp_path / "open.yaml"
    path.write_text("plant: {model: physical, litres: 50, lid: off}\n", encoding="utf-8")
    assert scenario.load_scenario(path).plant["lid"] is False


# ---------------------------------------------------------------- an outside plant

# A first-order tun written from the protocol's documentation alone (hermsd.sim.hlt.Plant).
OUTSIDE_TUN = """
import math
import os
import tempfile

class FirstOrderTun:
    def __init__(self):
        self.t = 0.0
        self.temp = 20.0
        self.ambient = 20.0
        self.litres = 90.0
        self.on = False
        self.ok = True

    def _to(self, t):
        power = 3000.0 if self.on and self.ok else 0.0
        heading = self.ambient + power / 17.76
        tau = self.litres * 4186.0 / 17.76
        self.temp = heading + (self.temp - heading) * math.exp(-(t - self.t) / tau)
        self.t = t

    def set_heater(self, on, t):
        self._to(t)
        self.on = on

    def set_element_ok(self, ok, t):
        self._to(t)
        self.ok = ok

    def set_ambient(self, temp_c, t):
        self._to(t)
        self.ambient = temp_c

    def add_water(self, litres, temp_c, t):
        self._to(t)
        self.temp = (self.litres * self.temp + litres * temp_c) / (self.litres + litres)
        self.litres += litres

    def temperature(self, t):
        self._to(t)
        return self.temp

    def water_temperature(self, t):
        return self.temperature(t)

def make_tun():
    return FirstOrderTun()

def make_nothing():
    return object()

def make_broken():
    raise RuntimeError("no such tun")
"""


def simulate(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    code = cli.main(["simulate", *args])
    out, err = capsys.readouterr()
    return code, out, err


def test_an_outside_plant_runs_through_the_daemon(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Full power from 20 °C heads for 20 + 3000/17.76 °C with τ = 90·4186/17.76 s, so the
    physical minimum to 65.5 °C is −τ·ln(1 − 45.5·17.76/3000)."""
    tun = tmp_path / "tun.py"
    tun.write_text(OUTSIDE_TUN, encoding="utf-8")
    code, out, err = simulate(capsys, "--plant", f"{tun}:make_tun", "--json")
    assert code == 0, err
    summary = json.loads(out)
    tau = 90.0 * 4186.0 / 17.76
    minimum = -tau * math.log(1.0 - 45.5 * 17.76 / 3000.0)
    assert summary["physical_min_s"] == pytest.approx(minimum, abs=0.1)
    assert summary["alarms"] == []
    assert summary["in_band_fraction"] == 1.0
    assert summary["recovery_min_s"] is not None


def test_an_outside_plant_can_come_from_an_importable_module(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    (tmp_path / "brewery_tun.py").write_text(OUTSIDE_TUN, encoding="utf-8")
    monkeypatch.syspath_prepend(str(tmp_path))
    short = short_day(tmp_path)
    code, out, err = simulate(capsys, "--plant", "brewery_tun:make_tun", "--scenario", short)
    assert code == 0, err
    assert "max_temp_c" in out


def test_the_simulators_own_tun_is_one_such_plant(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    reference = "hermsd.sim.hlt:PhysicalPlant"  # a class is a factory too
    code, out, err = simulate(capsys, "--plant", reference, "--scenario", short_day(tmp_path))
    assert code == 0, err
    assert "max_temp_c" in out


def short_day(directory: Path) -> str:
    """Twenty minutes of the default brew day, in a scenario file."""
    path = directory / "short.yaml"
    path.write_text("duration: 20m\nsetpoint: 66\n", encoding="utf-8")
    return str(path)


@pytest.mark.parametrize(
    ("reference", "message"),
    [
        ("{dir}/missing.py:make_tun", "no file"),
        ("{dir}/tun.py:make_tin", "has no function make_tin"),
        ("{dir}/tun.py:make_nothing", "lacks set_heater, set_element_ok"),
        ("{dir}/tun.py:make_broken", "make_broken() failed: RuntimeError: no such tun"),
        ("{dir}/syntax.py:make_tun", "cannot load"),
        ("no_such_module_here:make_tun", "cannot load no_such_module_here"),
        ("make_tun", "expected FILE.py:FACTORY"),
    ],
)
def test_a_plant_that_cannot_be_used_is_one_line_and_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], reference: str, message: str
) -> None:
    (tmp_path / "tun.py").write_text(OUTSIDE_TUN, encoding="utf-8")
    (tmp_path / "syntax.py").write_text("def make_tun(:\n", encoding="utf-8")
    code, out, err = simulate(capsys, "--plant", reference.format(dir=tmp_path))
    assert code == 2
    assert out == ""
    assert message in err
    assert "Traceback" not in err
    assert err.count("\n") == 1


# ------------------------------------------------------------- state across days


def test_simulate_keeps_the_state_directory_from_one_day_to_the_next(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Day 1 loses its element (a latched alarm); day 2 on the same state starts latched,
    heater off, as the service does after a restart; without the state it heats."""
    state = tmp_path / "state"
    dead = Path(__file__).resolve().parents[1] / "scenarios" / "element-dead.yaml"
    code, out, err = simulate(capsys, "--scenario", str(dead), "--state", str(state), "--json")
    assert code == 0, err
    assert [a["kind"] for a in json.loads(out)["alarms"]] == ["heater_not_heating"]
    short = short_day(tmp_path)
    code, out, err = simulate(capsys, "--scenario", short, "--state", str(state), "--json")
    assert code == 0, err
    day2 = json.loads(out)
    assert [(a["kind"], a["at_s"]) for a in day2["alarms"]] == [("heater_not_heating", 0.0)]
    assert day2["max_temp_c"] == pytest.approx(20.0, abs=0.1)  # never heated
    code, out, err = simulate(capsys, "--scenario", short, "--json")
    fresh = json.loads(out)
    assert fresh["alarms"] == []
    assert fresh["max_temp_c"] > 25.0


def test_the_recovery_minimum_is_measured_on_a_lagging_noisy_sensor() -> None:
    """Once the sensor lagged the water, the copy read 66 °C at the instant the water went
    in and the minimum came out 0 (no ratio). Full power from the mixed water Tm heads for
    H = 20 + 3000/17.76 °C with τ = 100·4186/17.76 s: the water reaches 65.5 °C after
    τ·ln((H − Tm)/(H − 65.5)); with 90 L held within ±0.5 °C of 66 and 10 L of 15 °C,
    Tm = 0.9·T + 1.5 lies in 60.45..61.35 °C, and the sensor follows within 2 lags."""
    ua, lag = 17.76, 10.0
    day = scenario.parse_scenario(
        {
            "plant": {
                "model": "physical",
                "ua_w_per_k": ua,
                "transport_delay_s": 0.0,
                "sensor_lag_s": lag,
                "noise_c": 0.03,
                "seed": 1,
            },
            "events": [{"at": "4h", "add_water": {"litres": 10, "temp": 15}}],
        }
    )
    summary = scenario.run(day).summary
    heading = 20.0 + 3000.0 / ua
    tau = 100.0 * WATER_J_PER_LITRE_K / ua

    def water_reaches_band(mixed: float) -> float:
        return tau * math.log((heading - mixed) / (heading - 65.5))

    earliest, latest = water_reaches_band(0.9 * 66.5 + 1.5), water_reaches_band(0.9 * 65.5 + 1.5)
    assert earliest <= summary["recovery_min_s"] <= latest + 2 * lag
    assert summary["recovery_ratio"] is not None


# ------------------------------------------------------------------- the family


def test_the_family_spans_the_brewers_range_and_every_tun_can_hold_66_c() -> None:
    """30–150 L, 1.5–11 kW, UA ±50 %, dead time 30–300 s, lid on and off, rooms at 5–30 °C;
    each reaches the band at full power within 3.5 h (the water comes at 4 h) and holds
    66 °C with a margin: its losses there, UA·(66 − T_room) plus the evaporation of an open
    surface, take at most 75 % of its element."""
    litres = [spec.litres for spec in FAMILY]
    watts = [spec.element_watts for spec in FAMILY]
    dead = [spec.transport_delay_s + spec.sensor_lag_s for spec in FAMILY]
    assert len(FAMILY) >= 12
    assert (min(litres), max(litres)) == (30, 150)
    assert (min(watts), max(watts)) == (1500, 11000)
    assert {min(s.ua_factor for s in FAMILY), max(s.ua_factor for s in FAMILY)} == {0.5, 1.5}
    assert (min(dead), max(dead)) == (30, 300)
    assert {spec.lid_off for spec in FAMILY} == {True, False}
    assert (min(s.ambient_c for s in FAMILY), max(s.ambient_c for s in FAMILY)) == (5, 30)
    for spec in FAMILY:
        surface = pot_surface_m2(spec.litres)
        evaporation = evaporation_w(66.0, spec.ambient_c, surface) if spec.lid_off else 0.0
        holding_w = spec.ua_w_per_k * (66.0 - spec.ambient_c) + evaporation
        assert holding_w <= 0.75 * spec.element_watts, spec.name
        params = {k: v for k, v in spec.plant().items() if k not in ("model", "noise_c", "seed")}
        to_band = scenario.time_to_band(
            PhysicalPlant(**params), 0.0, 66.0, 3.5 * 3600.0, element2=False
        )
        assert to_band is not None, spec.name


class _Ramp:
    """Water that rises 0.012 °C/s while heated and holds otherwise; the sensor is exact."""

    def __init__(self, temp: float) -> None:
        self.temp, self.since, self.on = temp, 0.0, False

    def set_heater(self, on: bool, t: float) -> None:
        self.temp, self.since, self.on = self.water_temperature(t), t, on

    def temperature(self, t: float) -> float:
        return self.water_temperature(t)

    def water_temperature(self, t: float) -> float:
        return self.temp + (0.012 * (t - self.since) if self.on else 0.0)


@pytest.mark.parametrize(
    ("seen", "expected"),
    [
        # From 60 °C to the band's edge 65.5 °C: 5.5 / 0.012 = 458.33 s of full power. Seen a
        # whole 5 s period late (a loop that acts once a period): off for it, 463.33 s; at
        # 40 % (2 s on, 3 s off): 461.33 s; at 100 %: 458.33 s.
        (5.0, [463.33, 461.33, 458.33]),
        # Seen at a reading 3 s after the water: off for 3 s, 461.33 s; at 40 % the 2 s
        # on-time comes first and 1 s is lost: 459.33 s; at 100 %, 458.33 s.
        (3.0, [461.33, 459.33, 458.33]),
    ],
)
def test_the_recovery_floor_waits_for_the_reading(seen: float, expected: list[float]) -> None:
    plant = _Ramp(60.0)
    floors = [
        scenario.reactive_floor(plant, 100.0, 66.0, 3600.0, 5.0, u, seen, element2=False)
        for u in (0, 40, 100)
    ]
    assert floors == pytest.approx(expected, abs=0.01)
    assert plant.water_temperature(1000.0) == 60.0  # on a copy: the plant is untouched


def test_the_first_reading_after_an_event_follows_the_daemons_read_schedule() -> None:
    # Reads at 0.5, 1.5, 2.5 … s: water at 14400 s is seen at 14400.5 s; an event at a
    # reading's own time is seen by it (the scenario's events run first).
    assert scenario.first_read_after(14400.0, 1.0) == 14400.5
    assert scenario.first_read_after(14400.5, 1.0) == 14400.5
    assert scenario.first_read_after(0.0, 2.0) == 1.0
    assert scenario.first_read_after(3.2, 2.0) == 5.0


@pytest.mark.parametrize("where", ["a-file", "a-file/logs", "unwritable"])
def test_a_log_directory_that_cannot_hold_a_log_is_refused_before_the_run(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    where: str,
) -> None:
    (tmp_path / "a-file").write_text("not a directory\n")
    directory = tmp_path / where
    if where == "unwritable":  # as a read-only mount or another user's directory is, even to root
        directory.mkdir()

        def refused(*args: object, **kwargs: object) -> None:
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES))

        monkeypatch.setattr(tempfile, "TemporaryFile", refused)
    code, out, err = simulate(capsys, "--log", str(directory))
    assert (code, out) == (2, "")
    assert err.startswith(f"hermsd: --log {directory}: cannot write a log there: ")
    assert err.count("\n") == 1 and "state directory" not in err
    assert (tmp_path / "a-file").read_text() == "not a directory\n"
    assert not list(tmp_path.rglob("*.mcap*"))


def test_an_attached_outer_loop_steers_the_daemon_and_ends_the_day() -> None:
    """`run(attach=...)` hands the daemon over before it runs: a listener that sets the
    setpoint at 10 min (applied at the next period boundary, as a socket's command) and stops
    the day at 2 h of 4 is obeyed, the records saying so, and the day is measured to where it
    ended (its last hour the one before 2 h, not an empty one before 4 h)."""

    class Outer:
        def __init__(self, daemon: Daemon) -> None:
            self.daemon = daemon

        def period(self, record: PeriodRecord) -> None:
            if record.t >= 600.0 and self.daemon.setpoint != 40.0:
                self.daemon.set_setpoint(40.0)
            if record.t >= 7200.0:
                self.daemon.stop()

        def alarm(self, alarm: Alarm) -> None:
            """No alarm is expected on this day."""

    def attach(daemon: Daemon) -> None:
        daemon.listeners.append(Outer(daemon))

    day = scenario.Scenario(duration=4 * 3600.0, setpoint=60.0, events=())
    result = scenario.run(day, keep_records=True, attach=attach)
    records = result.records
    assert {r.setpoint for r in records if r.t < 600.0} == {60.0}
    assert {r.setpoint for r in records if r.t > 610.0} == {40.0}
    assert 7200.0 <= records[-1].t < 7210.0
    assert result.summary["last_hour_p2p_c"] is not None
