"""The peers the benchmarks compare hermsd with, behind the daemon's controller interface.

- simple-pid 2.0.1 (the `bench` dependency group), with its own integral and output limits;
- CraftBeerPi 4's PIDAutotune kettle logic (its relay autotune; `CraftBeerPiAutotune`);
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
import math
from collections import deque
from collections.abc import Iterator
from typing import Any
from unittest import mock

from hermsd.config.schema import ControlConfig
from hermsd.control import factory
from hermsd.control.pid import PlantModel

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
        out = self._pid(pv, dt=self._ts)
        if out is None:  # simple-pid answers None only in manual mode, which `reset` leaves
            raise RuntimeError("simple-pid is in manual mode: it computed no output")
        p, i, d = self._pid.components
        self.terms = (float(p), float(i), float(d))
        return float(out)


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

    def make(control: ControlConfig, model: PlantModel | None = None) -> Any:
        """The peer, duck-typed: no `Controller`, but the loop only resets and steps it and
        reads its terms. It has no use for `model`."""
        return peer_class(gains["kc"], gains["ti"], gains["td"], control.period)

    with mock.patch.object(factory, "make_controller", make):  # as build.control_law calls it
        yield


class CraftBeerPiAutotune:
    """CraftBeerPi 4's PIDAutotune kettle logic (after the Arduino PID AutoTune library),
    rewritten here from its published algorithm, one call a sample (its 5 s):

    - a relay from an initial output of 0: `outputstep` above it (clipped to 0..`maxout`)
      until the input exceeds setpoint + noiseband, then `outputstep` below it (so 0 %)
      until it falls under setpoint − noiseband; the setpoint is the kettle's, truncated to
      a whole degree; noiseband 0.5 °C;
    - a sample is a peak when it is above (below) every sample of the lookback window
      (60 s by default); a change between maximum and minimum counts a peak (its value and
      time kept, the last five);
    - after more than four peaks, at each new one: the induced amplitude is the sum of the
      three absolute differences between the oldest four of the last five peaks, over 6;
      it has converged when half the spread of those peaks exceeds it by less than 5 %;
      then Ku = 4·outputstep/(π·amplitude) and Pu the mean of the two spans between peaks
      two apart; it gives up at 20 peaks.
    """

    def __init__(
        self,
        setpoint: float,
        outputstep: float = 100.0,
        maxout: float = 100.0,
        lookback_s: float = 60.0,
        sample_s: float = 5.0,
        noiseband: float = 0.5,
    ) -> None:
        self.setpoint = float(int(setpoint))
        self.outputstep = outputstep
        self.maxout = maxout
        self.noiseband = noiseband
        self.window: deque[float] = deque(maxlen=round(lookback_s / sample_s))
        self.peaks: deque[float] = deque(maxlen=5)
        self.peak_times: deque[float] = deque(maxlen=5)
        self.peak_type = 0
        self.peak_count = 0
        self.stepping_up = True
        self.output = min(outputstep, maxout)
        self.state = "running"
        self.ku = math.nan
        self.pu = math.nan

    def start(self, t: float) -> None:
        self.peak_times.append(t)  # as the original: the start counts as the first time

    def sample(self, value: float, t: float) -> bool:
        """One sample at `t` s; True when done (state 'succeeded' or 'failed')."""
        if self.stepping_up and value > self.setpoint + self.noiseband:
            self.stepping_up = False
        elif not self.stepping_up and value < self.setpoint - self.noiseband:
            self.stepping_up = True
        step = self.outputstep if self.stepping_up else -self.outputstep
        self.output = min(max(step, 0.0), self.maxout)
        is_max = all(value > old for old in self.window)
        is_min = all(value < old for old in self.window)
        self.window.append(value)
        if len(self.window) < (self.window.maxlen or 0):
            return False
        turned = False
        if is_max:
            turned, self.peak_type = self.peak_type == -1, 1
        elif is_min:
            turned, self.peak_type = self.peak_type == 1, -1
        if turned:
            self.peak_count += 1
            self.peaks.append(value)
            self.peak_times.append(t)
        if turned and self.peak_count > 4:
            peaks = list(self.peaks)
            highest = lowest = peaks[-2]
            amplitude = 0.0
            for i in range(len(peaks) - 2):
                amplitude += abs(peaks[i] - peaks[i + 1])
                highest, lowest = max(peaks[i], highest), min(peaks[i], lowest)
            amplitude /= 6.0
            if (0.5 * (highest - lowest) - amplitude) / amplitude < 0.05:
                times = list(self.peak_times)
                self.ku = 4.0 * self.outputstep / (amplitude * math.pi)
                self.pu = 0.5 * ((times[3] - times[1]) + (times[4] - times[2]))
                self.state, self.output = "succeeded", 0.0
                return True
        if self.peak_count >= 20:
            self.state, self.output = "failed", 0.0
            return True
        return False
