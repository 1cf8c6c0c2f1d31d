"""The mash side of a HERMS in the loop: the sensors beside the HLT's (the mash's, the coil
outlet's), read with the HLT's at its read interval, and the pump, switched as commanded.

Neither acts on the heater: the HLT's loop holds the HLT as before, so a mash sensor's fault
is a warning in the status, not an alarm. Every change of the pump is an event in the log
and a journal line; the pump is off at the start and at the stop (docs/herms.md).
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, TypedDict

from hermsd.config.schema import ROLE_SENSORS, SafetyConfig
from hermsd.hardware.lm92 import SensorError
from hermsd.program.runner import MashReading
from hermsd.runtime.loop_state import LoopState
from hermsd.runtime.notify import mash_side_words
from hermsd.safety.coil_load import NO_LOAD, CoilLoad, coil_load

if TYPE_CHECKING:
    from hermsd.hardware.sensors.base import Sensor
    from hermsd.runtime.parts import Parts


class PumpNotFitted(ValueError):
    """The pump was commanded, but the config fits none."""


Said = tuple[int, str]
"""What a role's sensor has to say: a logging level and the message."""
NO_PUMP = "pump: no pump is fitted (set pump.backend in the config file and restart hermsd)"


class RoleSensor:
    """One sensor in a role beside the HLT's: its latest good reading, and its fault, said
    when it begins (after `safety.fault_reads` failed or implausible reads in a row, as the
    HLT's, by the safety section in force) and when it ends."""

    def __init__(self, role: str, sensor: Sensor) -> None:
        self.role = role
        self.sensor = sensor
        self.celsius: float | None = None  # None while faulty, or before a good read
        self.fault: str | None = None
        self._failures = 0

    def start(self, safety: SafetyConfig) -> Said | None:
        """Check the chip and read it once; what there is to say (a fault), else None. A
        chip that is wrong or missing is a fault from the start: the HLT does not need it."""
        try:
            self.sensor.identify()
            self.sensor.wake()
        except SensorError as error:
            self._failures = safety.fault_reads - 1
            return self._failed(str(error), safety)
        return self.read(safety)

    def read(self, safety: SafetyConfig) -> Said | None:
        """Read once; a fault begun or ended, else None."""
        try:
            celsius = self.sensor.read().celsius
        except SensorError as error:
            return self._failed(str(error), safety)
        low, high = safety.plausible_min, safety.plausible_max
        if not low <= celsius <= high:
            return self._failed(
                f"{celsius:.2f} °C is outside safety.plausible_min to plausible_max "
                f"({low:g} to {high:g} °C)",
                safety,
            )
        self._failures = 0
        self.celsius = celsius
        if self.fault is None:
            return None
        self.fault = None
        return logging.INFO, f"{self.role} sensor reads again: {celsius:.2f} °C"

    def _failed(self, why: str, safety: SafetyConfig) -> Said | None:
        self._failures += 1
        if self.fault is not None or self._failures < safety.fault_reads:
            return None  # the last good reading stands until the fault is declared
        self.fault, self.celsius = why, None
        return logging.WARNING, f"{self.role} sensor fault: {why} (the HLT is held as before)"


def role_sensors(parts: Parts) -> dict[str, RoleSensor]:
    """The fitted sensors beside the HLT's, by their config section."""
    given = {"mash_sensor": parts.mash_sensor, "coil_sensor": parts.coil_sensor}
    return {
        section: RoleSensor(ROLE_SENSORS[section], sensor)
        for section, sensor in given.items()
        if sensor is not None
    }


class MashSideFields(TypedDict):
    """What a period record holds of the mash side (`PeriodRecord`'s fields)."""

    mash: float | None
    coil: float | None
    pump: bool | None


class MashSide(LoopState):
    """The Daemon's sensors beside the HLT's and its pump."""

    _roles: dict[str, RoleSensor]
    _pump_on: bool
    _program_pump_step: tuple[int, bool] | None  # the program's step the pump was set for

    @property
    def pump_fitted(self) -> bool:
        return self.outputs.pump is not None

    def set_pump(self, on: bool, reason: str) -> None:
        """Run or stop the pump at once, said with `reason` (on the loop's thread: an
        operator's command at a period boundary, a program's step); PumpNotFitted when the
        config fits none."""
        pump = self.outputs.pump
        if pump is None:
            raise PumpNotFitted(NO_PUMP)
        if on != self._pump_on:
            self._pump_on = on
            pump.set(on)
            self._event(logging.INFO, f"pump {'on' if on else 'off'}: {reason}", self._now())

    def mash_reading(self) -> MashReading | None:
        """What a program times its rests on the mash by (None: no mash sensor fitted)."""
        mash = self._roles.get("mash_sensor")
        return None if mash is None else MashReading(mash.celsius)

    def _program_pump(self) -> None:
        """Switch the pump as the program's step says, once when the step begins (and once
        after a restart): `hermsd set pump` within a step stands until the next one."""
        wanted = self.program.pump_step()
        if wanted == self._program_pump_step:
            return
        self._program_pump_step = wanted
        runner = self.program.runner
        if wanted is None or runner is None or not self.pump_fitted:
            return
        step = runner.step
        self.set_pump(wanted[1], f"program {runner.program.name!r}, step {step.name!r}")

    def _start_mash_side(self) -> None:
        self._pump_on = False
        self._program_pump_step = None
        for role in self._roles.values():
            self._say_role(role.start(self.config.safety))

    def _read_mash_side(self) -> None:
        """Read each sensor beside the HLT's, and refresh the pump's switch (a relay board's
        off is said again now and then: `GuardedSwitch`)."""
        for role in self._roles.values():
            self._say_role(role.read(self.config.safety))
        if self.outputs.pump is not None:
            self.outputs.pump.set(self._pump_on)

    def _say_role(self, said: Said | None) -> None:
        if said is not None:
            self._event(*said, self._now())

    def _stop_mash_side(self, reason: str, t: float) -> None:
        """Said when the stop switched a running pump off (with every output)."""
        if self._pump_on:
            self._pump_on = False
            self._event(logging.INFO, f"pump off: {reason}", t)

    def mash_side_fields(self) -> MashSideFields:
        """The period record's mash, coil outlet and pump (None: not fitted, or faulty)."""
        mash, coil = self._roles.get("mash_sensor"), self._roles.get("coil_sensor")
        return {
            "mash": None if mash is None else mash.celsius,
            "coil": None if coil is None else coil.celsius,
            "pump": self._pump_on if self.pump_fitted else None,
        }

    def coil_load(self, hlt: float | None) -> CoilLoad:
        """The coil's load on the HLT at `hlt` °C, for the supervisor's heat balances: none
        without a mash sensor (no HERMS known) or with the pump hermsd switches off; counted
        with a pump hermsd does not switch, which may be running (docs/herms.md, "The coil
        and the safety")."""
        mash = self._roles.get("mash_sensor")
        if mash is None or hlt is None:
            return NO_LOAD
        pump = self._pump_on if self.pump_fitted else None
        return coil_load(hlt, mash.celsius, pump, self.config.herms.max_coil_flow)

    def mash_words(self) -> str:
        """The status line's 'mash 64.8 °C, pump on' (`notify.mash_side_words`)."""
        return mash_side_words(self.role_status()["mash"], self.mash_side_fields()["pump"])

    def role_status(self) -> dict[str, dict[str, object] | None]:
        """The status reply's `mash` and `coil`: null when not fitted, else the reading (°C,
        null while faulty) and the fault in words (null when there is none)."""
        status: dict[str, dict[str, object] | None] = {}
        for section, role in ROLE_SENSORS.items():
            sensor = self._roles.get(section)
            key = role.split()[0]
            status[key] = (
                None if sensor is None else {"celsius": sensor.celsius, "fault": sensor.fault}
            )
        return status

    def _now(self) -> float:
        return self.clock.monotonic()
