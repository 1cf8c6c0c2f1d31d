"""The outputs a daemon drives: the SSR's switch and the second element's, each guarded so a
failing switch turns the heater off, and the HERMS pump's; the seam where the simulator's
outputs plug in."""

from __future__ import annotations

import math
from dataclasses import dataclass

from hermsd.config.schema import Config
from hermsd.hardware.ssr import (
    GuardedSwitch,
    Switch,
)
from hermsd.runtime.clock import Clock


@dataclass(slots=True)
class Outputs:
    """The SSR and, optionally, a series contactor and a second element, behind dead-men; and
    the pump, when one is fitted."""

    ssr: GuardedSwitch
    contactor: GuardedSwitch | None = None
    element2: GuardedSwitch | None = None
    pump: GuardedSwitch | None = None

    def all(self) -> list[GuardedSwitch]:
        """Every output: each is off at the start and at the stop."""
        outputs = (self.ssr, self.contactor, self.element2, self.pump)
        return [s for s in outputs if s is not None]


def guard_outputs(
    ssr: Switch,
    contactor: Switch | None,
    clock: Clock,
    config: Config,
    element2: Switch | None = None,
    pump: Switch | None = None,
) -> Outputs:
    """Wrap raw outputs in dead-men that trip after two windows without a refresh (the
    second element, refreshed once a period: two periods). The pump's never trips: a pump is
    no heater, and wort circulating while the loop is silent harms nothing (it is off when
    hermsd stops)."""
    timeout = 2.0 * window_length(config)
    slow = 2.0 * max(window_length(config), config.control.period)
    return Outputs(
        GuardedSwitch(ssr, clock.monotonic, timeout, "ssr"),
        GuardedSwitch(contactor, clock.monotonic, timeout, "contactor") if contactor else None,
        GuardedSwitch(element2, clock.monotonic, slow, "element2") if element2 else None,
        GuardedSwitch(pump, clock.monotonic, math.inf, "pump") if pump else None,
    )


def window_length(config: Config) -> float:
    return config.output.window if config.output.window is not None else config.control.period
