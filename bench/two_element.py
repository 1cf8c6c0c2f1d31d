"""The two-element tun (2 kW SSR + 3.5 kW contactor): shared out and mid-ranging, beside
their alternatives.

Each tun is one of the family's physics (hermsd.sim.tuns: UA scaled from the seed's tun by
the wetted area, transport delay, sensor lag, noise sd 0.03 °C before the LM92's steps) on a
brew day: room temperature to 66 °C, a tenth of the volume of 15 °C water at 4 h, 6 h in
all; then the same day with a fault in the hold (5 h). Four ways to heat it:

- shared out: the SSR's 2 kW element and a 3.5 kW element on a contactor (min on and off
  120 s), the shipped default controller (predictive) on the total power of both, the
  contactor decided first each period and the SSR making up the difference
  (hermsd.control.element2.PowerSplit), through the daemon;
- midrange: the same elements, `control.algorithm: midrange` with the shipped settings;
- one 5.5 kW element on an SSR, the shipped default controller (predictive): the peer;
- on/off: both elements on one contactor (5.5 kW), a thermostat with hysteresis ±0.25 °C
  about the setpoint on the same readings and the same 120 s minimum on and off times
  (simulated here on the same tun, sensor and clock: the daemon has no on/off controller).

Goals: overshoot ≤ 0.1 °C; settle and recovery within ×1.02 of the 5.5 kW SSR's; the
contactor at most 30 operations an hour in the hold (from the settle to the end, the
recovery included); a dead element of either kind and a shorted contactor caught
(detection time after the fault).

    uv run python bench/midrange.py --tun [--write]
"""

from __future__ import annotations

import dataclasses
import math
import random
import sys
import time
from typing import Any

from hermsd.config import schema as config_module
from hermsd.metrics import Sample, compute
from hermsd.safety.element_watch import no_heat_words
from hermsd.sim.hlt import PhysicalPlant
from hermsd.sim.scenario import Event, Scenario, run
from hermsd.sim.tuns import NOISE_C, TunSpec

SSR_W, CONTACTOR_W = 2000.0, 3500.0
MIN_ON = MIN_OFF = 120.0
FAULT_AT = 5 * 3600.0
HYSTERESIS = 0.25  # °C either side of the setpoint, for on/off

TUNS = (
    TunSpec("90 L lidded", 90, SSR_W + CONTACTOR_W, 1.0, 60, 10, 20),
    TunSpec("60 L lidded", 60, SSR_W + CONTACTOR_W, 1.0, 45, 10, 20),
    TunSpec("150 L lid off", 150, SSR_W + CONTACTOR_W, 1.5, 90, 20, 12, lid_off=True),
)

TWO: dict[str, dict[str, Any]] = {
    "tun": {"element_watts": SSR_W},
    "control": {},
    "element2": {"backend": "sim", "watts": CONTACTOR_W, "min_on": MIN_ON, "min_off": MIN_OFF},
}
MIDRANGE = {"algorithm": "midrange"}


def two_element_day(spec: TunSpec, control: dict[str, Any] | None = None) -> Scenario:
    day = spec.brew_day()
    plant = {**day.plant, "element_watts": SSR_W, "element2_watts": CONTACTOR_W}
    config = {**TWO, "tun": {**TWO["tun"], "litres": spec.litres}}
    if control:
        config["control"] = {**config["control"], **control}
    name = (control or {}).get("algorithm", "predictive")
    return dataclasses.replace(day, name=f"{spec.name} {name}", plant=plant, config=config)


def one_element_day(spec: TunSpec) -> Scenario:
    day = spec.brew_day()
    config = {"tun": {"element_watts": spec.element_watts, "litres": spec.litres}}
    return dataclasses.replace(day, name=f"{spec.name} 5.5 kW SSR", config=config)


def contactor_operations(edges: list[float], start: float | None, end: float) -> float | None:
    """Operations an hour from `start` (the settle) to `end`."""
    if start is None or end <= start:
        return None
    return sum(1 for t in edges if start <= t < end) * 3600.0 / (end - start)


def two_element_row(spec: TunSpec, control: dict[str, Any] | None = None) -> dict[str, Any]:
    result = run(two_element_day(spec, control), keep_records=True)
    s = result.summary
    relay_edges = [
        r.t
        for a, r in zip(result.records, result.records[1:], strict=False)
        if (a.switched2 == 0.0) != (r.switched2 == 0.0)
    ]
    settle = s["settle_s"]
    return {
        "overshoot": s["overshoot_c"],
        "settle": settle,
        "recovery": s["recovery_s"],
        "ops": contactor_operations(relay_edges, settle, s["duration_s"]),
        "ssr_edges": s["ssr_edges_per_hour"],
    }


WATER_SHIFTS = (0.0, 60.0, 120.0, 180.0, 240.0, 300.0)
"""s after 4 h: where the water lands in the contactor's cycle (a hold between the ranges
cycles it every 300–380 s, and a minimum off time may hold it off when the water comes)."""


def shifted(day: Scenario, shift: float) -> Scenario:
    events = tuple(
        dataclasses.replace(e, at=e.at + shift) if e.kind == "add_water" else e for e in day.events
    )
    return dataclasses.replace(day, events=events)


def recovery_spread(spec: TunSpec) -> tuple[float, float]:
    """The least and greatest recovery ×SSR (shared out) over the water times of WATER_SHIFTS."""
    ratios = []
    for shift in WATER_SHIFTS:
        two = run(shifted(two_element_day(spec), shift)).summary["recovery_s"]
        one = run(shifted(one_element_day(spec), shift)).summary["recovery_s"]
        ratios.append(two / one if two is not None and one else math.inf)
    return min(ratios), max(ratios)


def on_off_row(spec: TunSpec, seed: int = 1) -> dict[str, Any]:
    """A thermostat on one 5.5 kW contactor, read every second, switched within its minimums."""
    plant = PhysicalPlant(
        litres=spec.litres,
        element_watts=spec.element_watts,
        ua_w_per_k=spec.ua_w_per_k,
        transport_delay_s=spec.transport_delay_s,
        sensor_lag_s=spec.sensor_lag_s,
        lid=not spec.lid_off,
        ambient_c=spec.ambient_c,
    )
    rng = random.Random(seed)
    setpoint, duration, water_at = 66.0, 6 * 3600.0, 4 * 3600.0
    on, since, edges, samples = False, -math.inf, [], []
    watered = False
    for step in range(int(duration)):
        t = float(step)
        if not watered and t >= water_at:
            plant.add_water(spec.litres / 10.0, 15.0, t)
            watered = True
        reading = math.floor((plant.temperature(t) + rng.gauss(0.0, NOISE_C)) / 0.0625) * 0.0625
        want = reading < setpoint - HYSTERESIS if not on else reading < setpoint + HYSTERESIS
        if want != on and t - since >= (MIN_ON if on else MIN_OFF):
            on, since = want, t
            plant.set_heater(on, t)
            edges.append(t)
        if step % 5 == 0:
            samples.append(Sample(t, setpoint, plant.temperature(t), 100.0 if on else 0.0))
    m = compute(samples, [water_at], duration)
    return {
        "overshoot": m.overshoot_c,
        "settle": m.settle_s,
        "recovery": m.recovery_s,
        "ops": contactor_operations(edges, m.settle_s, duration),
        "ssr_edges": 0.0,
    }


def ssr_row(spec: TunSpec) -> dict[str, Any]:
    s = run(one_element_day(spec)).summary
    return {
        "overshoot": s["overshoot_c"],
        "settle": s["settle_s"],
        "recovery": s["recovery_s"],
        "ops": 0.0,
        "ssr_edges": s["ssr_edges_per_hour"],
    }


FAULTS = (
    ("SSR element dead", "heater", "open", FAULT_AT, False),
    ("contactor element dead", "heater2", "open", FAULT_AT, False),
    ("contactor element dead, water at 5 h 30", "heater2", "open", FAULT_AT, True),
    ("SSR element dead from the start", "heater", "open", 1.0, False),
    ("contactor element dead from the start", "heater2", "open", 1.0, False),
    ("contactor shorted", "relay2", "stuck_on", FAULT_AT, False),
)
"""(column, fault, its value, when, water again at SECOND_WATER)."""
SECOND_WATER = 5.5 * 3600.0
"""s: a tenth of the volume of 15 °C water again, which asks the contactor's element for heat
(a lidded tun holds on the SSR alone, and a dead element nothing asks for shows nothing)."""


def first_warning(records: list[Any], after: float) -> tuple[int, float] | None:
    """The first element reported giving no heat at or after `after`, and when (s after)."""
    for record in records:
        if record.t >= after and record.no_heat:
            return record.no_heat[0], record.t - after
    return None


def normal_warnings(spec: TunSpec) -> int:
    """Element warnings on the shared-out normal days with the water at each of WATER_SHIFTS."""
    found = 0
    for shift in WATER_SHIFTS:
        records = run(shifted(two_element_day(spec), shift), keep_records=True).records
        found += first_warning(records, 0.0) is not None
    return found


def fault_row(
    spec: TunSpec,
    kind: str,
    value: str,
    control: dict[str, Any] | None = None,
    water: bool = False,
    at: float = FAULT_AT,
) -> tuple[str, float | None, float, tuple[int, float] | None]:
    """The first alarm after the fault at `at`, how long after it ((-, None): not caught),
    the highest PV above the setpoint from the fault to the alarm (or the day's end), °C, and
    the first element warning (element, s after the fault); `water` adds water at
    SECOND_WATER."""
    day = two_element_day(spec, control)
    config = {**day.config, "contactor": {"backend": "gpio", "line": 27}}
    events = (*day.events, Event(at, kind, value))
    if water:
        litres = spec.litres / 10.0
        events += (Event(SECOND_WATER, "add_water", {"litres": litres, "temp": 15.0}),)
    result = run(dataclasses.replace(day, config=config, events=events), keep_records=True)
    caught = [a for a in result.summary["alarms"] if a["detected_after_s"] is not None]
    alarm, after = (caught[0]["kind"], caught[0]["detected_after_s"]) if caught else ("-", None)
    end = math.inf if after is None else at + after
    over = max(
        (r.pv - r.setpoint for r in result.records if at <= r.t <= end and r.pv is not None),
        default=0.0,
    )
    return alarm, after, over, first_warning(result.records, at)


OPEN_POT_NOTE = (
    "Shared out, the lidded tuns hold on the SSR alone (0.6–0.8 kW, under its 2 kW): the "
    "contactor switches only at the heat-up's end and the recovery, and the figures are the "
    "5.5 kW SSR's. The 150 L open pot needs some 2.5 kW (45 %) to hold: between what the SSR "
    "gives alone (36.4 %) and the least with the contactor on (63.6 %). The contactor then "
    "cycles: on for its 120 s minimum with the SSR off, 1025 W too much, then off with the SSR "
    "full. 1025 W for 120 s into 150 L is 0.196 °C, so a ripple held about the setpoint "
    "peaks some 0.1 °C over it whatever the controller does; the pot's overshoot above is "
    "that ripple and the sensor's noise (its heat-up alone overshoots some 0.1 °C). Less "
    "would need "
    "a shorter minimum on time or a mean held below the setpoint. A minimum off time also "
    "holds the contactor off for 120 s after each opening: water that lands then waits for "
    "it, up to 120 s of 3.5 kW (×1.08 below); water that lands while it is on starts on "
    "both at once (×0.99)."
)

FAULT_NOTE = (
    "The supervisor judges the total power switched on (both elements' duties as one % of "
    "5.5 kW), with limits that hold for any fill from half to twice the configured litres. "
    "A dead element shows where the other cannot hold the tun alone: both outputs then run "
    "at 100 % and the water falls (heater_not_heating). Where the other can, the loop holds "
    "the setpoint on the element that works, and the temperature alone cannot tell a dead "
    "element from losses that grew by its power (a lid taken off): whenever one element's "
    "duty is steady, 'element i gives nothing' and 'the tun loses its power more' move the "
    "water alike, and the fill range (×4) is wider than the two elements' ratio, so no rise "
    "or rate judged against the limits separates them. Shared out, a lidded tun holds on "
    "the SSR alone, so the contactor's element is not asked for in the hold: its death "
    "shows only in the next heat-up or recovery, which then runs on 2 kW (slower, and not "
    "an alarm by the limits). A dead SSR element in such a hold is made up by the contactor "
    "cycling at its minimum times (the peak above). A shorted contactor is caught by heat "
    "beyond what was switched (ssr_stuck_on): within the 300 s watch where its 3.5 kW far "
    "outruns the losses, by the 900 s watch on the open pot (hermsd/safety/supervisor.py, "
    "CREEP_WATCHES). "
    "In quotes: the element watch's first warning (hermsd/safety/element_watch.py, "
    "docs/two-elements.md), which switches nothing, judged against the same day's "
    "full-power rise and hold power, so the fill cancels out ('more heat than asked?' is "
    "what it says of a shorted contactor, before the supervisor's alarm). "
    "The contactor's element in a lidded hold is never asked for (the SSR holds alone): its "
    "death cannot show until heat is asked of it, so the column with a tenth of the water "
    "again at 5 h 30 shows when it is (the 150 L pot asks for it all through its hold, and "
    "the supervisor latches there too, as neither element holds it alone). An element dead "
    "from the start of the day leaves the watch's references without its heat; shared out, "
    "the heat-up's check (element2.check: the SSR's element off for 60 s, well below the "
    "setpoint) names it when it is judged, 2329 s into the day on these tuns; the 150 L pot "
    "on its SSR's element alone never reaches the setpoint (it needs 2.5 kW): no alarm "
    "says so (its water never falls at full power), the warning setpoint_unreachable does "
    "(both elements on at full, the level named from their rise: hermsd/control/reach.py). "
    "Named, an element is no longer asked and the other holds alone (docs/two-elements.md): "
    "the SSR's 2 kW the lidded tuns, after a slow approach where the contactor died before "
    "the heat-up's fit. Mid-ranging has no such check. "
    "Mid-ranging pulses the contactor for about as much as the SSR's part in the hold: the "
    "90 L tun's dead SSR element is told as element 1 or 2; the 60 and 150 L ones are not "
    "told."
)


def _cell(value: float | None, digits: int = 0) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def _ratio(value: float | None, peer: float | None) -> str:
    return "-" if value is None or not peer else f"{value / peer:.3f}"


def _goals(row: dict[str, Any], peer: dict[str, Any]) -> str:
    met = [
        row["overshoot"] <= 0.1,
        row["settle"] is not None and peer["settle"] and row["settle"] <= 1.02 * peer["settle"],
        row["recovery"] is not None
        and peer["recovery"]
        and row["recovery"] <= 1.02 * peer["recovery"],
        row["ops"] is not None and row["ops"] <= 30.0,
    ]
    return f"{sum(bool(m) for m in met)} of 4"


def main(write: bool = False) -> int:
    started = time.perf_counter()
    c = config_module.DEFAULT.control
    settings = (
        f"k1 {c.k1:g}, ti1 {c.ti1:g} s, tt1 {c.tt1:g} s, k2 {c.k2:g}, ti2 {c.ti2:g} s, "
        f"tt2 = ti2, ks {c.ks:g}, u1_ref {c.u1_ref:g} %"
    )
    out = [
        "A 2 kW element on the SSR and a "
        f"3.5 kW one on a contactor (min on and off {MIN_ON:g} s), heated two ways: the "
        "shipped default controller (predictive) on the total power of both, shared out each "
        "period (the contactor decided first, the SSR making up the difference: "
        "docs/two-elements.md), and `control.algorithm: midrange` with its shipped settings "
        f"({settings}); beside one 5.5 kW element on an SSR with the default controller (the "
        "peer: ×SSR is the ratio to it) and a ±0.25 °C thermostat switching both elements on "
        "one contactor within the same minimum times. The family's physics (hermsd.sim.tuns), "
        "noise sd 0.03 °C; the brew day of the family (66 °C, a tenth of the volume of 15 °C "
        "water at 4 h). Overshoot: the highest the sensor's true temperature goes over the "
        "setpoint all day (the heat-up's, the recovery's and the hold's ripple). Contactor "
        "operations an hour from the settle to the end of the day. Goals: overshoot ≤ 0.1 °C, "
        "settle and recovery ≤ ×1.02 the peer's, ≤ 30 operations an hour.",
        "",
        "| tun | heating | overshoot °C | settle s | ×SSR | recovery s | ×SSR | "
        "contactor ops/h | goals |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for spec in TUNS:
        peer = ssr_row(spec)
        rows = (
            ("predictive 2 + 3.5 kW, shared out", two_element_row(spec)),
            ("midrange 2 + 3.5 kW", two_element_row(spec, MIDRANGE)),
            ("5.5 kW SSR, predictive", peer),
            ("on/off 5.5 kW contactor", on_off_row(spec)),
        )
        for label, row in rows:
            out.append(
                f"| {spec.name} | {label} | {row['overshoot']:.3f} | {_cell(row['settle'])} | "
                f"{_ratio(row['settle'], peer['settle'])} | {_cell(row['recovery'])} | "
                f"{_ratio(row['recovery'], peer['recovery'])} | {_cell(row['ops'], 1)} | "
                f"{_goals(row, peer)} |"
            )
        print(f"{spec.name} done", file=sys.stderr, flush=True)
    out += [
        "",
        OPEN_POT_NOTE,
        "",
        "The shared-out recovery with the water at 4 h plus "
        + ", ".join(f"{w:g}" for w in WATER_SHIFTS)
        + " s (where it lands in the contactor's cycle), ×SSR against the peer's on the "
        "same day: least and greatest.",
        "",
        "| tun | recovery ×SSR, least | greatest |",
        "|---|---|---|",
    ]
    for spec in TUNS:
        low, high = recovery_spread(spec)
        out.append(f"| {spec.name} | {low:.3f} | {high:.3f} |")
    out += [
        "",
        "Element warnings (hermsd/safety/element_watch.py) on the same normal days, shared out, "
        "the water at each of those times: "
        + ", ".join(f"{spec.name} {normal_warnings(spec)} of {len(WATER_SHIFTS)}" for spec in TUNS)
        + ".",
    ]
    out += [
        "",
        f"Faults in the hold (at {FAULT_AT / 3600:g} h, or from the start: 1 s, a series "
        "contactor fitted): the first element warning and the first alarm, each with its "
        "time after the fault, and the highest PV over the setpoint from the fault to the "
        "alarm or the day's end (peak; from the start, the heat-up's included).",
        "",
        "| tun | heating | " + " | ".join(fault[0] for fault in FAULTS) + " |",
        "|---|---|" + "---|" * len(FAULTS),
    ]
    for spec in TUNS:
        for label, control in (("shared out", None), ("midrange", MIDRANGE)):
            cells = []
            for _, kind, value, at, water in FAULTS:
                alarm, after, over, warned = fault_row(spec, kind, value, control, water, at)
                said = (
                    []
                    if warned is None
                    else [f"'{no_heat_words(warned[0])}' after {warned[1]:.0f} s"]
                )
                caught = [] if after is None else [f"{alarm} after {after:.0f} s"]
                cells.append(f"{'; '.join(said + caught) or 'not caught'} (peak SP {over:+.2f} °C)")
            out.append(f"| {spec.name} | {label} | " + " | ".join(cells) + " |")
    out += [
        "",
        FAULT_NOTE,
        "",
        f"Run time {time.perf_counter() - started:.0f} s.",
    ]
    text = "\n".join(out) + "\n"
    print(text)
    if write:
        import sections  # bench/sections.py, beside this file

        sections.write("## Mid-ranging: the two-element tun", text)
    return 0


if __name__ == "__main__":
    sys.exit(main("--write" in sys.argv[1:]))
