"""Whether both elements heat, checked once in the first heat-up (docs/two-elements.md).

The element watch judges the day against references measured the same day, so an element
dead from the start leaves them without its heat and is never seen. Here, in a full-power
spell well below the setpoint, the SSR's element is switched off for `PROBE_S` while the
second stays on. Its missing heat P1·t/C shows, after the dead time and the sensor's lag,
as an offset ΔT between the PV's trend lines before and after (fitted with one slope
over `FIT_S` on each side, the offset taken midway between them, where the heat-up's bend
from growing losses moves both alike). Against the rise over the same time r·t = (P1 + P2 − L)·t/C:

    share = ΔT / (r·t) = P1 / (P1 + P2 − L)

which the fill (C) does not enter: about P1/(P1 + P2) when both heat (a little more with
the losses L), 0 when the SSR's element is dead, 1 or more when the second is (the probe
then stops all heating). It costs P1·t of heat, some P1/(P1 + P2)·t of the heat-up's time.

Pure: stepped with the controller (one control period a step), so `hermsd replay --verify`
re-runs the same probe from the period records.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from hermsd.safety.element_watch import SUDDEN_FALL, SUDDEN_SPAN

PROBE_S = 60.0
"""s the SSR's element is off: 2 kW for 60 s into 45 L (the least fill of a 90 L config) is
0.64 °C, into 300 L 0.1 °C."""
FIT_S = (120.0, 600.0)
"""s of PV on each side, the least and the most: as long as the heat-up leaves time for,
the same on both sides (the offset between them is taken midway between their middles,
where a heat-up's bend, quadratic in time, moves both sides alike). The slope's error
weighs in over the gap between them, so longer is quieter (its sd goes as length^-1.5)."""
SETTLE_S = 300.0
"""s beyond twice the dead time before a side starts (from full power, or from the probe's
end): a thermowell's lag of up to 150 s bends the rise for two lags and more, and the dead
time may be misjudged by as much again (a far sensor's 240 s against the default 115 s)."""
BELOW = 10.0
"""°C: the whole probe, its fits included, lies this far below the setpoint (nothing of it
reaches the approach, so it costs no overshoot)."""
SSR_DEAD = 0.5
"""A share under this part of the SSR element's nominal one says it gives no heat."""
OTHER_DEAD = 0.5
"""A share over the nominal one by this part of the way to 1 says the second gives none."""
SIGMAS = 3.0
"""A finding must also lie this many standard errors of the share (from the fits'
residuals) from the nominal share: a noisy heat-up (a small element into much water, a
lid-off tun's steam) is said to be not checked rather than misread."""


@dataclass(frozen=True, slots=True)
class ProbeResult:
    """What the probe found: the dead element (1: the SSR's, 2: the second), none, and why;
    the share of the rise the probe took (None: not judged)."""

    element: int | None
    message: str
    share: float | None = None


class ElementProbe:
    """Switches the SSR's element off once, early in the first full-power heat-up, and
    judges from the PV which element heats."""

    def __init__(self, watts1: float, watts2: float, period: float, dead_time: float) -> None:
        if not (watts1 > 0.0 and watts2 > 0.0 and period > 0.0 and dead_time >= 0.0):
            raise ValueError(f"watts and period must be > 0: {watts1}, {watts2}, {period}")
        self.nominal = watts1 / (watts1 + watts2)
        self.period = period
        self.dead_time = dead_time
        self.result: ProbeResult | None = None  # the finding, until taken
        self.done = False  # probed, or said why not: once a controller's life
        self._t = 0.0  # s: steps × period since the controller was made
        self._spell: list[tuple[float, float]] = []  # (t, PV) since full power on both began
        self._start: float | None = None  # when the probe began
        self._width = 0.0  # s of PV fitted on each side of it

    def take(self) -> ProbeResult | None:
        """The finding not yet reported, once."""
        result, self.result = self.result, None
        return result

    def abandon(self) -> None:
        """The loop held the controller (an alarm, manual, a program waiting): no spell
        spans that, and a probe in progress is given up."""
        if self._start is not None:
            self._finish(None, "elements not checked: the probe was interrupted")
        self._spell.clear()

    def step(self, setpoint: float, pv: float, full: bool) -> bool:
        """One control period with both elements asked `full`: whether the SSR's element is
        off for the probe in it."""
        self._t += self.period
        t = self._t
        if self.done:
            return False
        if not full:
            if self._start is not None:
                self._finish(None, "elements not checked: full power ended within the probe")
            elif self._spell and setpoint - pv < BELOW:
                self._finish(None, "elements not checked: no full-power spell long enough")
            self._spell.clear()
            return False
        spell = self._spell
        spell.append((t, pv))
        lead = 2.0 * self.dead_time + SETTLE_S
        if self._start is None:
            if setpoint - pv < BELOW:
                self._finish(None, "elements not checked: no full-power spell long enough")
                return False
            width = t - spell[0][0] - lead
            if width < FIT_S[0] - 1e-9:
                return False
            slope, _ = _line([s for s in spell if s[0] > t - FIT_S[0]])
            left = setpoint - BELOW - pv  # °C the rise may take until the probe is judged
            if slope <= 0.0 or slope * (PROBE_S + lead + width) > left:
                self._finish(None, "elements not checked: too little time before the setpoint")
                return False
            # Wider sides while the heat-up leaves time for one more period on each.
            wider = PROBE_S + lead + width + 2.0 * self.period
            if width < FIT_S[1] - 1e-9 and slope * wider <= left:
                return False
            self._start, self._width = t, width
        start, width = self._start, self._width
        end = start + PROBE_S
        if t < end - 1e-9:
            return True
        if t < end + lead + width - 1e-9:
            return False
        judged = [s for s in spell if s[0] > start - width]
        if _fell(judged):
            self._finish(None, "elements not checked: the water fell in the heat-up (added?)")
            return False
        self._judge(
            [s for s in spell if start - width < s[0] <= start],
            [s for s in spell if s[0] > end + lead],
        )
        return False

    def _judge(self, before: list[tuple[float, float]], after: list[tuple[float, float]]) -> None:
        """Both sides on lines of one slope (the rise's, midway between them, for a bend
        quadratic in time), each with its own level: the levels' difference is the heat the
        probe did not give; its standard error from the residuals."""
        sides = [(_mean_t(side), _mean_y(side), side) for side in (before, after)]
        stt = sum((t - mt) ** 2 for mt, _, side in sides for t, _ in side)
        slope = sum((t - mt) * (y - my) for mt, my, side in sides for t, y in side) / stt
        (t_b, y_b, _), (t_a, y_a, _) = sides
        offset = y_b + slope * (t_a - t_b) - y_a
        rise = slope * PROBE_S
        n = len(before) + len(after)
        rss = sum((y - my - slope * (t - mt)) ** 2 for mt, my, side in sides for t, y in side)
        var = rss / max(1, n - 3)
        if rise <= 0.0:
            self._finish(None, "elements not checked: the water did not rise")
            return
        share = offset / rise
        error = math.sqrt(var / len(before) + var / len(after) + (t_a - t_b) ** 2 * var / stt)
        error /= rise  # the share's standard error
        said = (
            f"{100.0 * share:.0f} ± {100.0 * error:.0f} % of the rise missing with the "
            f"SSR's element off for {PROBE_S:.0f} s in the heat-up ({100.0 * self.nominal:.0f} "
            "% if both heat)"
        )
        if share < SSR_DEAD * self.nominal and share + SIGMAS * error < self.nominal:
            self._finish(1, f"element 1 gives no heat? {said}", share)
        elif (
            share > self.nominal + OTHER_DEAD * (1.0 - self.nominal)
            and share - SIGMAS * error > self.nominal
        ):
            self._finish(2, f"element 2 gives no heat? {said}", share)
        elif SIGMAS * error < SSR_DEAD * self.nominal:
            self._finish(None, f"both elements heat: {said}", share)
        else:
            self._finish(None, f"elements not checked: the PV too noisy for it: {said}")

    def _finish(self, element: int | None, message: str, share: float | None = None) -> None:
        self.result = ProbeResult(element, message, share)
        self.done = True
        self._start = None
        self._spell.clear()


def _fell(points: list[tuple[float, float]]) -> bool:
    """Whether the PV fell, at full power, as only added water makes it (the element watch's
    SUDDEN_FALL within SUDDEN_SPAN): the level it leaves behind is no missing heat."""
    first = 0  # the first point within SUDDEN_SPAN before the one judged
    for i, (t, pv) in enumerate(points):
        while points[first][0] < t - SUDDEN_SPAN:
            first += 1
        if i > first and max(y for _, y in points[first:i]) - pv >= SUDDEN_FALL:
            return True
    return False


def _mean_t(points: list[tuple[float, float]]) -> float:
    return sum(t for t, _ in points) / len(points)


def _mean_y(points: list[tuple[float, float]]) -> float:
    return sum(y for _, y in points) / len(points)


def _line(points: list[tuple[float, float]]) -> tuple[float, float]:
    """(slope, intercept) of the least-squares line through `points`."""
    n = len(points)
    mean_t = _mean_t(points)
    mean_y = sum(y for _, y in points) / n
    stt = sum((t - mean_t) ** 2 for t, _ in points)
    slope = sum((t - mean_t) * (y - mean_y) for t, y in points) / stt
    return slope, mean_y - slope * mean_t
