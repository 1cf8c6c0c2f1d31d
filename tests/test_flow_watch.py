"""The no-flow sign (`control/flow_watch.py`): the pump runs, the mash does not take the coil's
heat. Golden counts by hand from the module's rule (docs/mash-control.md, "No flow through
the coil"):

An HLT of 400 kJ/K and a mash of 200 kJ/K, the larger's reading error 3 × 0.0625 °C ×
400 kJ/K = 75 kJ, a stretch is judged once the heat expected is twice that, 150 kJ. A coil
of K = 200 W/K (one sd low) with the HLT 5 K above the mash passes 200 × 5 × 5 s = 5 kJ a
5 s period: a stretch of 30 periods is judged. The mash's losses are 0 here, so the heat it
takes is C_m times its rise: 5 kJ is 0.025 °C a period.
"""

from __future__ import annotations

from hermsd.control.coil import Exchange
from hermsd.control.flow_watch import FlowWatch

PERIOD, K, DRIVE = 5.0, 200.0, 5.0
FLOWING = Exchange(PERIOD * DRIVE, K * PERIOD * DRIVE)
STANDING = Exchange(PERIOD * DRIVE, 0.0)


class Tanks:
    """A FlowWatch fed period by period, the mash's reading kept."""

    def __init__(self) -> None:
        self.watch = FlowWatch(hlt_capacity=400e3, mash_capacity=200e3, delays=10.0, period=PERIOD)
        self.mash = 60.0
        self.watch.period(
            None, self.mash, pump=True, mash_loss=0.0, room=20.0, k=K
        )  # the first reading

    def feed(self, exchange: Exchange, n: int, *, pump: bool = True) -> list[bool]:
        """`n` periods of `exchange`, the mash rising by what the HLT gave; the changes."""
        changes = []
        for _ in range(n):
            self.mash += exchange.heat / 200e3
            changes.append(
                self.watch.period(exchange, self.mash, pump=pump, mash_loss=0.0, room=20.0, k=K)
            )
        return changes


def test_a_coil_that_passes_its_heat_raises_no_sign() -> None:
    tanks = Tanks()
    assert tanks.feed(FLOWING, 400) == [False] * 400
    assert not tanks.watch.stuck


def test_no_flow_is_signed_once_a_stretch_is_judged_and_ends_when_the_flow_shows() -> None:
    tanks = Tanks()
    assert tanks.feed(STANDING, 29) == [False] * 29  # 145 kJ expected: not judged yet
    assert tanks.feed(STANDING, 1) == [True] and tanks.watch.stuck
    assert tanks.feed(STANDING, 100) == [False] * 100
    # Flowing again: the last 30 periods judged, their mean over half the 150 kJ expected
    # once more than 15 of them passed 5 kJ each.
    assert tanks.feed(FLOWING, 15) == [False] * 15 and tanks.watch.stuck
    assert tanks.feed(FLOWING, 1) == [True] and not tanks.watch.stuck


def test_heat_flowing_back_from_a_warmer_mash_is_flow() -> None:
    tanks = Tanks()
    back = Exchange(-PERIOD * DRIVE, -K * PERIOD * DRIVE)  # the mash gives 5 kJ a period
    assert tanks.feed(back, 400) == [False] * 400
    assert not tanks.watch.stuck


def test_too_little_drive_across_the_coil_judges_nothing() -> None:
    """0.1 K across the coil: 100 J a period, 1,500 periods for a judged stretch, more than
    the 30 min looked back over."""
    tanks = Tanks()
    assert tanks.feed(Exchange(PERIOD * 0.1, 0.0), 1000) == [False] * 1000


def test_the_pump_stopped_ends_the_sign() -> None:
    tanks = Tanks()
    tanks.feed(STANDING, 30)
    assert tanks.watch.stuck
    assert tanks.watch.period(None, tanks.mash, pump=False, mash_loss=0.0, room=20.0, k=K)
    assert not tanks.watch.stuck


def test_a_sign_just_raised_is_not_cleared_by_the_flow_before_it() -> None:
    """Flowing 40 periods, then standing: raised at the 16th standing period (the last 30
    hold 14 flowing, 70 kJ, under half the 150 kJ expected on both sides). A reading's step
    then (+0.0625 °C of the mash, 12.5 kJ) puts the same 30 periods' mash at 77.5 kJ, over
    the half: a stretch reaching back to the flow before the sign, which cleared it and let
    the next period raise it again. Only a stretch wholly after the raise may clear it."""
    tanks = Tanks()
    tanks.feed(FLOWING, 40)
    assert tanks.feed(STANDING, 16) == [False] * 15 + [True]
    tanks.mash += 0.0625
    assert not tanks.watch.period(STANDING, tanks.mash, pump=True, mash_loss=0.0, room=20.0, k=K)
    assert tanks.watch.stuck
    # Flowing again: judged on the 30 periods after the raise once there are 30 (the step's
    # and 29 flowing, 157.5 kJ), where a stretch of them first shows the flow.
    assert tanks.feed(FLOWING, 29) == [False] * 28 + [True]
    assert not tanks.watch.stuck
