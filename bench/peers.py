"""The peers the benchmarks compare hermsd with, behind the daemon's controller interface.

- simple-pid 2.0.1 (the `bench` dependency group), with its own integral and output limits;
- CraftBeerPi 4's PIDHerms kettle logic, its control law rewritten here from its behaviour:
  a positional PID in parallel form, P and I on the error, D on the measurement without a
  filter, the integral frozen while the last output sat at a limit, the output clamped to
  0..100 %. Like the original it starts with a measurement history of 0 (its first sample
  kicks the derivative) and a restart builds a fresh one.

`controlled_by` swaps the daemon's controller for a peer for the length of a `with` block,
so that a peer runs through the very same daemon, sensor and heater as hermsd.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from typing import Any

from hermsd import daemon as daemon_module

ITAE_LOAD = {"kc": 80.8, "ti": 489.0, "td": 44.9}
"""Seed 001's Table 2 "ITAE-load" PID set for its identified tun: what a brewer would copy."""


class SimplePid:
    """simple-pid 2.0.1 behind the controller interface (it keeps its own integral)."""

    def __init__(self, kc: float, ti: float, td: float, ts: float) -> None:
        from simple_pid import PID

        self._pid = PID(kc, kc / ti, kc * td, setpoint=0.0, sample_time=None)
        self._pid.output_limits = (0.0, 100.0)
        self._ts = ts
        self.terms = (0.0, 0.0, 0.0)

    def reset(self, pv: float, output: float) -> None:
        self._pid.set_auto_mode(True, last_output=output)

    def step(self, sp: float, pv: float, applied: float | None = None) -> float:
        self._pid.setpoint = sp
        out = float(self._pid(pv, dt=self._ts))
        self.terms = tuple(float(c) for c in self._pid.components)  # type: ignore[assignment]
        return out


class PidHerms:
    """CraftBeerPi 4's PIDHerms: P = Kc, I = Kc/Ti per second, D = Kc·Td seconds, sampled
    every `ts` s: out = P·e + Σ I·ts·e − (D/ts)·Δpv, the sum frozen while the previous output
    was at 0 or 100 %."""

    def __init__(self, kc: float, ti: float, td: float, ts: float) -> None:
        self._p = kc
        self._i_per_sample = kc / ti * ts
        self._d_per_sample = kc * td / ts
        self.terms = (0.0, 0.0, 0.0)
        self._integral = 0.0
        self._last_pv = 0.0
        self._last_output = 0.0

    def reset(self, pv: float, output: float) -> None:
        """A (re)started kettle logic: a fresh controller, as the original builds one."""
        self._integral = 0.0
        self._last_pv = 0.0
        self._last_output = 0.0

    def step(self, sp: float, pv: float, applied: float | None = None) -> float:
        error = sp - pv
        if 0.0 < self._last_output < 100.0:
            self._integral = min(max(self._integral + self._i_per_sample * error, 0.0), 100.0)
        p = self._p * error
        d = -self._d_per_sample * (pv - self._last_pv)
        self._last_output = min(max(p + self._integral + d, 0.0), 100.0)
        self._last_pv = pv
        self.terms = (p, self._integral, d)
        return self._last_output


PEERS: dict[str, type[SimplePid] | type[PidHerms]] = {
    "simple-pid": SimplePid,
    "CraftBeerPi PIDHerms": PidHerms,
}


@contextlib.contextmanager
def controlled_by(peer: str, gains: dict[str, float]) -> Iterator[None]:
    """The daemon builds `peer` with `gains` instead of its configured controller."""
    peer_class = PEERS[peer]
    original: Callable[..., Any] = daemon_module.make_controller

    def make(control: Any, model: Any = None) -> Any:  # a peer has no use for the tun model
        return peer_class(gains["kc"], gains["ti"], gains["td"], control.period)

    daemon_module.make_controller = make
    try:
        yield
    finally:
        daemon_module.make_controller = original
