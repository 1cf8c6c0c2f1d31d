"""Switching a fake DS18B20 or MAX31865 into a fault: the name checked, a spike's value too."""

from __future__ import annotations

import math
from enum import StrEnum
from typing import TypeVar

_F = TypeVar("_F", bound=StrEnum)


def chosen(faults: type[_F], kind: str, value: float | None, chip: str) -> tuple[_F, float]:
    """The fault named `kind` and its value (a spike's °C; 0 for the others)."""
    try:
        fault = faults(kind)
    except ValueError:
        names = ", ".join(f.value for f in faults)
        raise ValueError(f"unknown {chip} fault {kind!r}: expected one of {names}") from None
    if fault.value == "spike" and (value is None or not math.isfinite(value)):
        raise ValueError(f"the 'spike' fault needs a finite temperature in °C, got {value}")
    return fault, value or 0.0
