"""The simulated heater circuit: SSR and contactor in series feeding the tun model's element.

Faults a scenario can inject live here: an SSR that fails shorted (stuck on). A scenario's
circuit keeps every SSR edge and every change of the element's power with its time, so the
simulator can count edges and tell exactly when the heater really went off after an alarm;
the circuit of `hermsd run --simulate`, which may run for weeks, keeps none (`history`).
"""

from __future__ import annotations

from collections.abc import Callable

from hermsd.sim.hlt import Plant


class HeaterCircuit:
    """SSR in series with an optional contactor; the element is powered when both conduct."""

    def __init__(
        self,
        plant: Plant,
        now: Callable[[], float],
        contactor: bool = False,
        *,
        history: bool = False,
    ) -> None:
        self._plant = plant
        self._now = now
        self._history = history
        self.ssr_on = False
        self.ssr_stuck_on = False
        self.contactor_closed = not contactor  # no contactor: the line is always made
        self.powered = False
        self.ssr_edges: list[float] = []
        self.power_changes: list[tuple[float, bool]] = []
        self.ssr = _Side(self._set_ssr)
        self.contactor = _Side(self._set_contactor) if contactor else None

    def set_stuck_on(self, stuck: bool) -> None:
        self.ssr_stuck_on = stuck
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
        powered = (self.ssr_on or self.ssr_stuck_on) and self.contactor_closed
        if powered != self.powered:
            t = self._now()
            self.powered = powered
            if self._history:
                self.power_changes.append((t, powered))
            self._plant.set_heater(powered, t)

    def off_at_or_after(self, t: float) -> float | None:
        """The first time at or after `t` when the element had no power (None: never).

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
