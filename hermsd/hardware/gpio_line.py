"""One GPIO line through the `gpiod` 2.x bindings (the `gpio` extra): the import that says
how to install them, and the line's request, for every output and input on a GPIO line."""

from __future__ import annotations

from typing import Any


class GpioLine:
    """One requested line: an output that starts inactive, or an input biased to its inactive
    level (a module unplugged reads inactive); `what` names it in the error when `gpiod` is
    not installed."""

    def __init__(self, chip: str, line: int, *, output: bool, active_low: bool, what: str) -> None:
        try:
            import gpiod
            from gpiod.line import Bias, Direction, Value
        except ImportError:
            raise ImportError(
                f"{what} needs the gpiod package, which is not installed (install the gpio "
                "extra: `uv sync --extra gpio`, or `pip install 'hermsd[gpio]'`)"
            ) from None

        self._line = line
        self._active, self._inactive = Value.ACTIVE, Value.INACTIVE
        direction: dict[str, Any] = (
            {"direction": Direction.OUTPUT, "output_value": Value.INACTIVE}
            if output
            else {"direction": Direction.INPUT}
        )
        settings = gpiod.LineSettings(
            **direction,
            active_low=active_low,
            bias=Bias.PULL_UP if active_low else Bias.PULL_DOWN,
        )
        self._request = gpiod.request_lines(chip, consumer="hermsd", config={line: settings})

    def active(self) -> bool:
        """Whether the line reads active (after active_low)."""
        return bool(self._request.get_value(self._line) == self._active)

    def set(self, active: bool) -> None:
        self._request.set_value(self._line, self._active if active else self._inactive)

    def release(self) -> None:
        self._request.release()
