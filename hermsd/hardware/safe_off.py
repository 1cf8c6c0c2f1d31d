"""`hermsd safe-off`: every output a config file names, driven off, whatever else is wrong.

It runs as systemd's `ExecStopPost=` after every stop, crashes included, when a bad edit
may be the very reason hermsd stopped. So it reads the file as far as it can
(`config.load_outputs`), switches off each device whose own keys say which one it is, and
says plainly what it could not: only an exit code of 0 means every output found is off.
"""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from hermsd.config.read import FoundOutput, FoundOutputs, every_valid_value
from hermsd.config.schema import ContactorConfig, Element2Config, OutputConfig, PumpConfig
from hermsd.hardware.ssr import Switch, describe_output

# The keys that say which device a backend drives, and which level is off. Without them
# there is nothing safe to switch: another port or line may be someone else's device.
_IDENTITY: dict[str, tuple[str, ...]] = {
    "serial-rts": ("port", "active_low"),
    "serial-dtr": ("port", "active_low"),
    "gpio": ("chip", "line", "active_low"),
    "relay-board": ("port",),
}
# Keys with a few valid values, each of which is tried when the written one is unusable:
# an off command at a wrong baud rate is noise to the board, and every relay of the
# contactor's board off is a safe state.
_TRIED_IN_TURN = ("baud", "channel")
_DEFAULTS: dict[str, OutputConfig | ContactorConfig | Element2Config | PumpConfig] = {
    "output": OutputConfig(),
    "contactor": ContactorConfig(),
    "element2": Element2Config(),
    "pump": PumpConfig(),
}
_ARGUMENTS = ("backend", "port", "chip", "line", "active_low", *_TRIED_IN_TURN)

OpenSwitch = Callable[..., Switch]


@dataclass
class Report:
    """What safe-off did: outputs switched off, and what keeps it from saying "all off"."""

    switched: list[str] = field(default_factory=list)
    failures: list[str] = field(default_factory=list)  # each makes the exit code non-zero
    notes: list[str] = field(default_factory=list)  # damage read around; changes nothing


def switch_off(found: FoundOutputs, open_switch: OpenSwitch) -> Report:
    """Drive the SSR output, the contactor, the second element and the pump off; every doubt
    about them is a failure. The pump too: nothing hermsd switches runs while it does not
    (docs/sensors.md, "The pump")."""
    report = Report()
    report.notes.extend(f"{problem}; read around it" for problem in found.notes)
    report.failures.extend(f"{problem}; so an output may be missed" for problem in found.doubts)
    for section in (found.output, found.contactor, found.element2, found.pump):
        _switch_section_off(section, open_switch, report)
    return report


def _switch_section_off(found: FoundOutput, open_switch: OpenSwitch, report: Report) -> None:
    name = found.section
    report.failures.extend(
        f"{problem}; so the {name} may be another device" for problem in found.doubts
    )
    if "backend" in found.refused:
        report.failures.append(f"{found.refused['backend']}; so the {name} is unknown")
        return
    settings = _settings(found)
    backend = settings["backend"]
    if backend in ("none", "sim"):
        return
    unusable = [found.refused[key] for key in _IDENTITY[backend] if key in found.refused]
    if unusable:
        report.failures.extend(f"{problem}; so the {name} is not switched" for problem in unusable)
        return
    tried = [key for key in _TRIED_IN_TURN if key in found.refused and key in settings]
    label = name if found.values else f"{name} (the built-in default)"
    each = ""
    if tried:
        keys = " and ".join(f"{name}.{key}" for key in tried)
        each = f" with each valid value of {keys}, which could not be used"
    attempts = list(itertools.product(*(every_valid_value(f"{name}.{k}") for k in tried)))
    errors: list[tuple[dict[str, Any], Exception]] = []
    for values in attempts:
        attempt = dict(settings, **dict(zip(tried, values, strict=True)))
        try:
            switch = open_switch(**attempt)
            try:
                switch.set(False)
            finally:
                switch.close()
        except Exception as error:  # whatever one device raises, the next is still tried
            errors.append((attempt, error))
    where = _where(label, settings, omit=tried)
    if tried and len(errors) == len(attempts):  # one line, not one per value tried
        report.failures.append(f"{where}: not switched off{each}: {errors[0][1]}")
    elif errors:
        report.failures.extend(
            f"{_where(label, attempt)}: not switched off: {error}" for attempt, error in errors
        )
    else:
        report.switched.append(f"{where}: off (sent{each})" if tried else f"{where}: off")


def _settings(found: FoundOutput) -> dict[str, Any]:
    """The arguments of the section's switch: its keys as written, defaults for the rest."""
    default = dataclasses.asdict(_DEFAULTS[found.section])
    return {key: found.values.get(key, default[key]) for key in _ARGUMENTS if key in default}


def _where(label: str, settings: dict[str, Any], omit: list[str] | None = None) -> str:
    """The device in words, with the settings tried (those in `omit` were tried in turn)."""
    shown = {key: value for key, value in settings.items() if key not in (omit or [])}
    where = describe_output(
        shown["backend"],
        port=shown["port"],
        chip=shown["chip"],
        line=shown["line"],
        channel=shown.get("channel"),
    )
    if "baud" in shown:
        where += f" at {shown['baud']} baud"
    return f"{label}: {where}"
