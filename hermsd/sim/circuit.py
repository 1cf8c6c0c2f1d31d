"""The simulated heater circuit: SSR and contactor in series feeding the tun model's element.

A second element, on its own relay or contactor, hangs behind the same series contactor.
Faults a scenario can inject live here: an SSR or the second element's relay that fails
shorted (stuck on), an element gone open. What a current transformer on the SSR's element
would read (`current.kind: sim`) is `CircuitCurrent`, with its own faults. A scenario's
circuit keeps every SSR edge and every change of the element's power with its time, so the
simulator can count edges and tell exactly when the heater really went off after an alarm;
the circuit of `hermsd run --simulate`, which may run for weeks, keeps none (`history`).
"""

from __future__ import annotations

import errno
from collections.abc import Callable
from enum import StrEnum

from hermsd.hardware.current_sense import CurrentRead
from hermsd.sim.fake_faults import chosen
from hermsd.sim.hlt import Plant, TwoElementPlant

MAINS_VOLTS = 230.0
"""The simulated mains: an element's amps are its watts over these volts."""


class HeaterCircuit:
    """SSR in series with an optional contactor; the element is powered when both conduct."""

    def __init__(
        self,
        plant: Plant,
        now: Callable[[], float],
        contactor: bool = False,
        *,
        history: bool = False,
        element2: TwoElementPlant | None = None,
    ) -> None:
        """`element2`: the plant again, as a tun with a second element, when one is fitted."""
        self._plant = plant
        self._now = now
        self._history = history
        self.ssr_on = False
        self.ssr_stuck_on = False
        self.element_ok = True
        self.contactor_closed = not contactor  # no contactor: the line is always made
        self.powered = False
        self._heating = False  # either element powered
        self.ssr_edges: list[float] = []
        self.power_changes: list[tuple[float, bool]] = []
        self.ssr = _Side(self._set_ssr)
        self.contactor = _Side(self._set_contactor) if contactor else None
        self._plant2 = element2
        self.relay2_on = False
        self.relay2_stuck_on = False
        self.powered2 = False
        self.relay2_edges: list[float] = []
        self.relay2 = _Side(self._set_relay2) if element2 is not None else None

    def set_stuck_on(self, stuck: bool) -> None:
        self.ssr_stuck_on = stuck
        self._update()

    def set_element_ok(self, ok: bool, t: float) -> None:
        """The SSR's element whole or open (it draws nothing, whatever switches it)."""
        self.element_ok = ok
        self._plant.set_element_ok(ok, t)

    @property
    def drawing(self) -> bool:
        """Whether current flows through the SSR's element: powered and whole."""
        return self.powered and self.element_ok

    def set_relay2_stuck_on(self, stuck: bool) -> None:
        if self.relay2 is None:
            raise ValueError("no second element is fitted (element2.backend is none)")
        self.relay2_stuck_on = stuck
        self._update()

    def _set_relay2(self, on: bool) -> None:
        if on != self.relay2_on:
            self.relay2_on = on
            if self._history:
                self.relay2_edges.append(self._now())
        self._update()

    def _set_ssr(self, on: bool) -> None:
        if on != self.ssr_on:
            self.ssr_on = on
            if self._history:
                self.ssr_edges.append(self._now())
        self._update()

    def _set_contactor(self, closed: bool) -> None:
        self.contactor_closed = closed
        self._update()

    def _update(self) -> None:
        t = self._now()
        powered = (self.ssr_on or self.ssr_stuck_on) and self.contactor_closed
        if powered != self.powered:
            self.powered = powered
            self._plant.set_heater(powered, t)
        if self._plant2 is not None:
            powered2 = (self.relay2_on or self.relay2_stuck_on) and self.contactor_closed
            if powered2 != self.powered2:
                self.powered2 = powered2
                self._plant2.set_heater2(powered2, t)
        heating = self.powered or self.powered2
        if heating != self._heating:
            self._heating = heating
            if self._history:
                self.power_changes.append((t, heating))

    def off_at_or_after(self, t: float) -> float | None:
        """The first time at or after `t` when no element had power (None: never).

        Needs the history; without it, ValueError.
        """
        if not self._history:
            raise ValueError("this circuit keeps no history of its power")
        state = False
        for when, powered in self.power_changes:
            if when > t:
                if not state:
                    return t
                if not powered:
                    return when
            state = powered
        return t if not state else None


class _Side:
    """One switch of the circuit, with the `Switch` interface the daemon drives."""

    def __init__(self, apply: Callable[[bool], None]) -> None:
        self._apply = apply

    def set(self, on: bool) -> None:
        self._apply(on)

    def close(self) -> None:
        self._apply(False)


class CurrentFault(StrEnum):
    """How the simulated current input misbehaves (`CircuitCurrent.set_fault`)."""

    OK = "ok"
    UNPLUGGED = "unplugged"
    """No signal: the CT off its wire or its plug out; it reads 0 A whatever flows."""
    FAILING = "failing"
    """Every read fails (an OSError, as a bus that NACKs)."""


class CircuitCurrent:
    """The SSR's element's current as a CT reads it (`current.kind: sim`): the element's amps
    at the simulated mains while the circuit powers it whole, else none."""

    def __init__(self, circuit: HeaterCircuit, element_watts: float, threshold: float) -> None:
        self._circuit = circuit
        self._amps = element_watts / MAINS_VOLTS
        self._threshold = threshold
        self.fault = CurrentFault.OK

    def set_fault(self, kind: str) -> None:
        self.fault, _ = chosen(CurrentFault, kind, None, "current input")

    def read(self) -> CurrentRead:
        if self.fault is CurrentFault.FAILING:
            raise OSError(errno.EREMOTEIO, "the current input cannot be read (simulated)")
        flowing = self._circuit.drawing and self.fault is CurrentFault.OK
        amps = self._amps if flowing else 0.0
        return CurrentRead(amps > self._threshold, amps)

    def close(self) -> None:
        """Nothing to release."""
