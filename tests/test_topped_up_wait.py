"""Water poured into the HLT while it waits for its `ready_by` is no loss of the tun's.

scenarios/step-mash.yaml's day (90 L, 3 kW, strike water at 72 °C by 06:30, waiting at 70 °C
from about 05:00), with the HLT topped up by 20 L of 15 °C water at 05:50: the water drops
to (90·70 + 20·15)/110 = 60 °C and climbs back at full power. That climb is the element's,
not the losses at the waiting temperature: taken for them, the schedule said full power
held the tun at 70.8 °C at most and could never reach 72 °C (it did, at 06:31:35).
"""

from __future__ import annotations

import re
from pathlib import Path

from hermsd.log import reader
from hermsd.program.readiness import LATE_S
from hermsd.sim import scenario

PROGRAM = Path(__file__).resolve().parents[1] / "scenarios" / "programs" / "step-mash.yaml"
DAY_START_S = 3.5 * 3600.0  # 03:30 local time


def test_water_poured_in_while_waiting_restarts_the_measurement_of_the_losses(
    tmp_path: Path,
) -> None:
    path = tmp_path / "topped-up.yaml"
    path.write_text(
        "name: topped-up\nduration: 3h15m\nclock: '2026-11-28T03:30:00+01:00'\n"
        "plant: {model: physical, litres: 90, element_watts: 3000, noise_c: 0.03, seed: 1}\n"
        f"program: {PROGRAM}\n"
        "events:\n  - {at: 2h20m, add_water: {litres: 20, temp: 15}}\n"
    )
    result = scenario.run(scenario.load_scenario(path), log_dir=tmp_path / "log")
    reached = result.summary["program"]["first_reached_s"]
    assert reached is not None
    events = reader.load(sorted((tmp_path / "log").glob("*.mcap"))).program
    said = [(e.event, e.message or "") for e in events if e.event in ("late", "release")]
    assert not [m for _, m in said if "at most" in m or m.endswith("never")], said
    [release] = [m for kind, m in said if kind == "release"]
    expected = re.search(r"expected (\d\d):(\d\d):(\d\d)$", release)
    assert expected is not None, release
    hours, minutes, seconds = (int(x) for x in expected.groups())
    expected_s = hours * 3600.0 + minutes * 60.0 + seconds - DAY_START_S
    assert abs(expected_s - reached) <= LATE_S
