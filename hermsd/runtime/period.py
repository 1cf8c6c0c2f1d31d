"""What one control period records: the loop's output, read by the log, the socket's history,
the simulator's measures and replay."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class PeriodRecord:
    """Everything the loop knew in one control period (logged, and what replay re-runs)."""

    t: float
    k: int
    setpoint: float
    pv: float | None
    readings: list[float]
    output: float
    applied: float
    p: float
    i: float
    d: float
    mode: str
    algorithm: str
    state: str
    alarms: list[str]
    heater_allowed: bool
    reset_from: float | None = None  # the controller was reset to this output before its step
    u2: float | None = None  # the second element's duty (two elements only), %
    applied2: float | None = None  # its duty in the period before, on account (C2 tracks it)
    switched2: float | None = None  # … and as switched (the heat the supervisor counts)
    full_from: int | None = None  # after this many of `readings` it asked for full power at once
    step: str | None = None  # the mash program's step (hermsd.program), its index from 0,
    step_index: int | None = None  # the time left of its hold (None: not reached, or held
    step_left_s: float | None = None  # until told), and the next step's name
    next_step: str | None = None
    on2: bool | None = None  # the second element was on as the period began
    free2: bool | None = None  # … and its minimum on or off time let it switch
    no_heat: list[int] | None = None  # the elements reported giving no heat (two elements)
    ceiling: float | None = None  # °C full power levels the water out at, while short (reach)
    mash: float | None = None  # °C, the mash sensor's latest good reading (None: not fitted,
    coil: float | None = None  # or faulty), the coil outlet's; the pump running (None: none
    pump: bool | None = None  # fitted)
    hlt_setpoint: float | None = None  # °C the outer loop set the HLT to (None: no mash
    coil_load: float | None = None  # sensor; `setpoint` is then the mash's), the coil's load
    cascade: str | None = None  # W fed forward, and the outer loop's phase
    pump_in: float | None = None  # s until a prepared pump start, when that load begins
    pump_stop_in: float | None = None  # s until a stop the program's timer announces
    coil_k: float | None = None  # W/K, the coil's K that load was reckoned on
    coil_load_met: bool | None = None  # False: that load a draw let act (None: fed forward)
    current: list[list[object]] | None = None  # the element's current input's samples (its
    current_said: list[str] | None = None  # CurrentWatch's), and what the watch said of them

    @property
    def hlt_target(self) -> float:
        """The setpoint the HLT law stepped to: the outer loop's, else the brewer's."""
        return self.setpoint if self.hlt_setpoint is None else self.hlt_setpoint
