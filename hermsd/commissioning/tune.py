"""Commissioning: the tun's model and the settings that follow from it.

- `table`: Table 1 of the PID calculus document (seed 001) for a model given by hand, printed
  as its Table 2 prints it.
- `from_log`: the model fitted to an ordinary brew day's logs (hermsd.commissioning.identify),
  how sure the fit is, Table 1 for it, and the settings it recommends for the config file.
"""

from __future__ import annotations

import dataclasses
import difflib
import json
import math
import re
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from decimal import ROUND_HALF_UP, Decimal
from pathlib import Path
from typing import Any

from ruamel.yaml import YAML
from ruamel.yaml.comments import CommentedMap
from ruamel.yaml.error import YAMLError

from hermsd.commissioning.identify import (
    MIN_DUTY_SPAN,
    UNCERTAINTY_METHOD,
    IdentifyError,
    TunModel,
    Uncertainty,
    fit_span,
    identify,
    uncertainty,
)
from hermsd.config import read
from hermsd.config import schema as config_module
from hermsd.control import seed
from hermsd.files import read_only, write_atomically
from hermsd.log.reader import Log, sudden_drops

# (title, rule prefix in pid.table1, the numbers the rule uses): Table 1's open-loop
# Ziegler–Nichols rows take the normalised slope a* and θ, all the others K, τ and θ.
RULES = (
    ("Ziegler-Nichols Open Loop", "zn_open", "θ, a*"),
    ("Ziegler-Nichols Closed Loop", "zn_closed", "K, τ, θ"),
    ("Cohen-Coon", "cohen_coon", "K, τ, θ"),
    ("ITAE-Load", "itae_load", "K, τ, θ"),
)
TABLE_KEYS = ("K", "tau", "theta", "a_star")
_UNITS = {"K": "°C/%", "tau": "s", "theta": "s", "a_star": "°C/(%·s)"}
MAX_TABLE_SETTING = 1e12
"""The largest Kc, Ti or Td the table prints: far beyond any tun's (the config takes Kc up to
1e4, Ti up to 1e5 s), and well within the 28 digits `printed` rounds in."""
A_STAR_MISMATCH = 0.1  # relative: a* and K/τ that differ more describe two different tuns


class TuneError(ValueError):
    """Input or logs that cannot be tuned from; the message is one line that says why."""


@dataclass(frozen=True, slots=True)
class Model:
    """The four numbers of Table 1: gain, time constant, dead time, normalised slope."""

    K: float  # °C/%
    tau: float  # s
    theta: float  # s
    a_star: float  # °C/(%·s)
    a_star_given: bool  # False: a* = K/τ, the FOPTD's own slope after its dead time

    def rules(self) -> dict[str, tuple[float, float, float]]:
        return seed.table1(K=self.K, tau=self.tau, theta=self.theta, a_star=self.a_star)


def parse_table(text: str) -> Model:
    """`K=1.689,tau=14961,theta=115,a_star=6.68e-5` (a_star optional: K/τ when left out)."""
    values: dict[str, float] = {}
    for item in filter(None, (part.strip() for part in text.split(","))):
        key, sep, value = (s.strip() for s in item.partition("="))
        if not sep or key not in TABLE_KEYS:
            raise TuneError(
                f"--table: {item!r} is not key=value with a key of {', '.join(TABLE_KEYS)} "
                "(e.g. K=1.689,tau=14961,theta=115,a_star=6.68e-5)"
            )
        if key in values:
            raise TuneError(f"--table: {key} is given twice")
        try:
            number = float(value)
        except ValueError:
            number = math.nan
        if not (math.isfinite(number) and number > 0):
            raise TuneError(
                f"--table: {key}={value!r}: {key} must be a number > 0 {_UNITS[key]}, finite"
            )
        values[key] = number
    missing = [key for key in TABLE_KEYS[:3] if key not in values]
    if missing:
        raise TuneError(f"--table: {', '.join(missing)} missing (K, tau and theta are needed)")
    given = "a_star" in values
    a_star = values["a_star"] if given else values["K"] / values["tau"]
    model = Model(values["K"], values["tau"], values["theta"], a_star, given)
    settings = [v for row in model.rules().values() for v in row]
    if not all(math.isfinite(v) and abs(v) < MAX_TABLE_SETTING for v in settings):
        raise TuneError(
            f"--table: {text}: the rules give settings beyond {MAX_TABLE_SETTING:g}, which no "
            "tun needs: check the units (K in °C/%, tau and theta in s, a_star in °C/(%·s))"
        )
    return model


def printed(value: float) -> str:
    """`value` to one decimal as a spreadsheet rounds it: the decimal value, half away from 0.

    The document's Table 2 does so: Ti = 3.33·115 = 382.95 is printed 383.0, where rounding
    the binary double (382.94999…) would give 382.9.
    """
    return str(Decimal(repr(value)).quantize(Decimal("0.1"), rounding=ROUND_HALF_UP))


def table_rows(model: Model) -> list[dict[str, Any]]:
    """Table 1 for `model`, one row per rule and form, in the document's order."""
    rules = model.rules()
    rows = []
    for title, prefix, uses in RULES:
        for form in ("pid", "pi"):
            kc, ti, td = rules[f"{prefix}_{form}"]
            rows.append(
                {
                    "method": title,
                    "form": form.upper(),
                    "kc": kc,
                    "ti": ti,
                    "td": td if form == "pid" else None,
                    "uses": uses,
                }
            )
    return rows


def table_lines(model: Model) -> list[str]:
    """The table as the document's Table 2 lays it out, with the numbers each rule uses."""
    slope = "given" if model.a_star_given else "= K/τ, none given"
    lines = [
        f"K {model.K:g} °C/%, τ {model.tau:g} s, θ {model.theta:g} s, "
        f"a* {model.a_star:.3g} °C/(%·s) ({slope})",
    ]
    ratio = model.a_star * model.tau / model.K
    if abs(ratio - 1.0) > A_STAR_MISMATCH:
        lines.append(
            f"note: a* is {ratio:.2f} × K/τ = {model.K / model.tau:.3g}: the open-loop rows "
            "(from a*) and the others (from K, τ) are for two different tuns"
        )
    width = max(len(title) for title, _, _ in RULES)
    lines.append(f"{'':{width}}  {'Kc [%/°C]':>9}  {'Ti [s]':>7}  {'Td [s]':>7}        uses")
    for row in table_rows(model):
        first = row["form"] == "PID"
        title = row["method"] if first else ""
        td = "--" if row["td"] is None else printed(row["td"])
        uses = row["uses"] if first else ""
        lines.append(
            f"{title:{width}}  {printed(row['kc']):>9}  {printed(row['ti']):>7}  {td:>7}  "
            f"{row['form']:<4}  {uses}".rstrip()
        )
    return lines


def table_json(model: Model) -> dict[str, Any]:
    return {"model": _asdict(model), "rules": table_rows(model)}


def _asdict(model: Model) -> dict[str, Any]:
    return {
        "K": model.K,
        "tau": model.tau,
        "theta": model.theta,
        "a_star": model.a_star,
        "a_star_given": model.a_star_given,
    }


# -- from a brew day's logs ---------------------------------------------------------------------

# The accuracy that commissioning aims at (and bench/tuning.py measures): within it at 2σ, the
# fit is called good.
GOAL_RELATIVE = 0.10  # of K and of τ
GOAL_DEAD_TIME_S = 20.0
WATER_J_PER_L_K = 4186.0
AMBIENT_RANGE_C = (-20.0, 50.0)  # control.model_ambient's range
MIN_HOLD_DRIVE_C = 5.0
"""°C: an open pot's hold at least this far above the room (below, its losses hardly show)."""
MAX_RMS_C = 0.04
"""°C: a first-order tun read by an LM92 (0.0625 °C steps, a period's mean of ~5 readings)
leaves a few hundredths; more is a tun the model does not describe."""


@dataclass(frozen=True, slots=True)
class Tuned:
    """The model of a logged day, how sure it is, and what it means for the settings."""

    model: TunModel
    uncertainty: Uncertainty
    a_star: float  # K/τ, °C/(%·s)
    confidence: str  # "good", or "poor: " and what is not pinned down
    recommended: dict[str, float]  # "section.key" → value
    implied_litres: float | None  # the water the fit implies at the logged element power
    logged_litres: float | None
    ambient_given: bool = False  # measured by the brewer (--ambient), not fitted
    evaporation: float | None = None  # E °C of an open pot's fit (tun.lid off); None: lidded
    hold: float | None = None  # °C: the setpoint whose static gain `model` gives (lid off)

    def table(self) -> Model:
        m = self.model
        return Model(m.gain, m.tau, m.dead_time, self.a_star, a_star_given=False)


def from_log(log: Log, ambient: float | None = None) -> Tuned:
    """Identify the tun from a day's log up to its first cold water or gap (identify.py).

    `ambient`: the room's temperature, when the brewer has measured it; else it is fitted.
    """
    if ambient is not None and not AMBIENT_RANGE_C[0] <= ambient <= AMBIENT_RANGE_C[1]:
        low, high = AMBIENT_RANGE_C
        raise TuneError(f"--ambient {ambient:g}: the room's temperature in °C, {low:g} to {high:g}")
    period_s = log.period_s()
    pvs = [p.pv for p in log.periods]
    n = fit_span(log, sudden_drops(log.elapsed, pvs), period_s)
    periods = log.periods[:n]
    duties = [p.applied for p in periods]
    if max(duties) - min(duties) < MIN_DUTY_SPAN:
        if all(p.mode == "manual" for p in periods):
            raise TuneError(
                f"the log is a manual-only day ({n} periods at {min(duties):g} to "
                f"{max(duties):g} %): the duty never stepped by {MIN_DUTY_SPAN:g} % or more, so "
                "the tun's gain and time constant do not show; log a day in auto with a "
                "heat-up and a hold, or step the manual output"
            )
        raise TuneError(
            f"no heat-up in the log: the duty stayed between {min(duties):g} and "
            f"{max(duties):g} % over the {n * period_s:g} s before the first cold water or gap; "
            "the fit needs a heat-up (full power, then the hold) to see gain and time constant"
        )
    watts, litres = _logged(log, "tun", "element_watts"), _logged(log, "tun", "litres")
    hold = None
    if _logged_text(log, "tun", "lid") == "off":
        setpoints = (p.setpoint for p in reversed(periods) if p.setpoint is not None)
        hold = next(setpoints, None)
        if hold is None:
            hold = _logged(log, "control", "setpoint")
        if hold is None:
            raise TuneError("the log's tun is an open pot, but no setpoint to hold is logged")
    return from_series(pvs[:n], duties, period_s, ambient, watts, litres, hold)


def from_series(
    pvs: Sequence[float | None],
    duties: Sequence[float],
    period_s: float,
    ambient: float | None = None,
    watts: float | None = None,
    litres: float | None = None,
    open_pot_hold: float | None = None,
) -> Tuned:
    """The model of one PV per control period and the duty applied over it, and its verdict.

    `watts` and `litres`: the config's element and water, to compare with what the fit implies.
    `open_pot_hold`: the tun is an open pot (tun.lid off) held at this setpoint: its
    evaporation is fitted (hermsd.commissioning.identify), and the model given is the static
    one at the hold (TunModel.at_hold): the duty that holds the setpoint, and the element's
    rate K/τ.
    """
    open_pot = open_pot_hold is not None
    try:
        fitted = identify(pvs, duties, period_s, ambient, evaporation=open_pot)
    except IdentifyError as error:
        raise TuneError(str(error)) from None
    if open_pot_hold is not None and not open_pot_hold > fitted.ambient + MIN_HOLD_DRIVE_C:
        raise TuneError(
            f"the setpoint {open_pot_hold:g} °C is not above the room's temperature "
            f"({fitted.ambient:.1f} °C) by {MIN_HOLD_DRIVE_C:g} °C or more: an open pot's model "
            "at the hold needs a hold that loses heat to the room"
        )
    spread = uncertainty(pvs, duties, period_s, fitted, ambient, open_pot_hold)
    model = fitted if open_pot_hold is None else fitted.at_hold(open_pot_hold)
    poor = []
    if 2 * spread.gain > GOAL_RELATIVE * model.gain:
        poor.append(f"K ±{100 * 2 * spread.gain / model.gain:.0f} %")
    if 2 * spread.tau > GOAL_RELATIVE * model.tau:
        poor.append(f"τ ±{100 * 2 * spread.tau / model.tau:.0f} %")
    if 2 * spread.dead_time > GOAL_DEAD_TIME_S:
        poor.append(f"θ ±{2 * spread.dead_time:.0f} s")
    if model.rms > MAX_RMS_C:
        why = "" if open_pot else " (an open pot? with tun.lid: off its evaporation is fitted)"
        poor.append(
            f"RMS {model.rms:.3f} °C: the model does not describe the tun over this log{why}"
        )
    if ambient is None and any(item.startswith(("K ", "τ ")) for item in poor):
        poor.append("the room's temperature (--ambient) pins K and τ")
    implied = None
    if watts is not None:
        implied = model.tau * watts / (100.0 * model.gain) / WATER_J_PER_L_K
    return Tuned(
        model=model,
        uncertainty=spread,
        a_star=model.gain / model.tau,
        confidence="good" if not poor else "poor at 2σ: " + "; ".join(poor),
        recommended=recommend(model, litres),
        implied_litres=implied,
        logged_litres=litres,
        ambient_given=ambient is not None,
        evaporation=fitted.evaporation if open_pot else None,
        hold=open_pot_hold,
    )


def recommend(model: TunModel, litres: float | None) -> dict[str, float]:
    """The predictive controller's model, rounded to what a fit can tell, and the water it
    was measured with (`litres`, the config's when the log was made: unknown, write_tuned
    takes the target file's): control.model_litres set is what makes the controller and the
    supervisor use the model instead of their prior."""
    settings = {
        "control.model_gain": float(f"{model.gain:.4g}"),
        "control.model_tau": float(round(model.tau)),
        "control.dead_time": float(round(model.dead_time)),
        "control.model_ambient": round(model.ambient, 1),
    }
    if litres is not None:
        settings["control.model_litres"] = litres
    return settings


def _logged_values(log: Log, section: str, key: str) -> Iterator[object]:
    """The key's value in each config record of the log, the last first."""
    for entry in reversed(log.configs):
        values = entry.config.get(section)
        yield values.get(key) if isinstance(values, dict) else None


def _logged_text(log: Log, section: str, key: str) -> str | None:
    """The value of the last config record that has it, as text (None: no record has it)."""
    return next((v for v in _logged_values(log, section, key) if isinstance(v, str)), None)


def _logged(log: Log, section: str, key: str) -> float | None:
    """The value of the last config record that has it, as a number."""
    for value in _logged_values(log, section, key):
        if isinstance(value, int | float) and not isinstance(value, bool):
            return float(value)
    return None


KEPT = {
    "control.kc, control.ti, control.td": "kept: the config's notes give them as suiting "
    "predictive on any tun, and no rule derives them from the model (the model keys carry "
    "the tun)",
    "control.learn": "kept: on, what the daemon learns on a later brew day comes before "
    "this model (it sees the losses at the hold, which a step that stops below the setpoint "
    "can only extrapolate to: an open pot's evaporation); pinned or off, this model is used "
    "as written",
    "safety": "no key to change: with control.model_litres set, the supervisor tightens "
    "its limits from this model (its MeasuredTun) within its own margins; safety.dead_time "
    "is best left null for that",
}


def tuned_json(tuned: Tuned) -> dict[str, Any]:
    return {
        "model": dataclasses.asdict(tuned.model),
        "uncertainty": dataclasses.asdict(tuned.uncertainty),
        "uncertainty_method": UNCERTAINTY_METHOD,
        "a_star": tuned.a_star,
        "confidence": tuned.confidence,
        "rules": table_rows(tuned.table()),
        "recommended": tuned.recommended,
        "kept": KEPT,
        "implied_litres": tuned.implied_litres,
        "logged_litres": tuned.logged_litres,
        "ambient_given": tuned.ambient_given,
        "evaporation": tuned.evaporation,
        "hold": tuned.hold,
    }


def tuned_lines(tuned: Tuned) -> list[str]:
    m, u = tuned.model, tuned.uncertainty
    lines = [
        f"tun model (fitted to the first {m.fit_s:g} s, RMS {m.rms:.3f} °C):",
        f"  K {m.gain:.4g} ± {u.gain:.2g} °C/%",
        f"  τ {m.tau:.0f} ± {u.tau:.0f} s",
        f"  θ {m.dead_time:g} ± {u.dead_time:.3g} s",
        f"  a* {tuned.a_star:.3g} °C/(%·s) (= K/τ)",
        f"  ambient {m.ambient:.1f} °C (given)"
        if tuned.ambient_given
        else f"  ambient {m.ambient:.1f} ± {u.ambient:.2g} °C",
        f"  confidence: {tuned.confidence} (± is one standard deviation, from the log's "
        "noise and from θ's whole periods; --json says how)",
    ]
    if tuned.evaporation is not None and tuned.hold is not None:
        lines[1:1] = [
            f"  an open pot (tun.lid off): K and τ are those at the hold, {tuned.hold:g} °C, "
            f"its evaporation ({tuned.evaporation:.1f} °C over the walls' losses there) "
            "included"
        ]
    if tuned.implied_litres is not None:
        logged = "" if tuned.logged_litres is None else f"; tun.litres is {tuned.logged_litres:g}"
        lines.append(
            f"  the fit implies {tuned.implied_litres:.0f} L of water at the logged element "
            f"power{logged} (the heater watches rely on tun.litres)"
        )
    lines += ["", "Table 1 for this model:", *table_lines(tuned.table())[1:], ""]
    lines.append("recommended settings:")
    lines += [f"  {key}: {value:g}" for key, value in tuned.recommended.items()]
    lines += [f"  {key}: {why}" for key, why in KEPT.items()]
    return lines


# -- writing the config file --------------------------------------------------------------------


def updated_config(text: str, filename: str, changes: Mapping[str, float | str]) -> str:
    """`text` with the values of `changes` ("section.key") replaced and nothing else.

    Every other byte stays as it was: each value is replaced where it is written (found by
    ruamel.yaml's round-trip positions), a key the file lacks gets a line of its own at the
    end of its section, indented as the section's keys are, with the file's own line ends.
    A dump of the document would re-indent lists and re-wrap long lines. The file must be a
    valid config before, and the result is checked as the daemon will check it.
    """
    _checked(text, filename, "is not a valid config now; fix it first")
    document = _positions(text, filename)
    lines = text.splitlines(keepends=True)
    newline = "\r\n" if text.endswith("\r\n") or "\r\n" in text[:4096] else "\n"
    if lines and not lines[-1].endswith(("\n", "\r")):
        lines[-1] += newline
    added: dict[int, list[str]] = {}  # after which line (-1: at the end), the lines added
    for path, value in changes.items():
        section, key = path.split(".")
        written = _scalar(value)
        block = document.get(section)
        if isinstance(block, CommentedMap) and block.fa.flow_style():
            raise TuneError(
                f"{filename}:{document.lc.key(section)[0] + 1}: {section} is written in flow "
                "style ({...}); write it as a block of key: value lines to let tune edit it"
            )
        if isinstance(block, CommentedMap) and key in block:
            row, column = block.lc.value(key)
            lines[row] = _with_scalar(lines[row], column, written)
        elif isinstance(block, CommentedMap) and block:
            indent = block.lc.key(next(iter(block)))[1]
            added.setdefault(_last_line(lines, document, section), []).append(
                f"{' ' * indent}{key}: {written}{newline}"
            )
        elif section in document:  # `section:` with nothing under it
            added.setdefault(document.lc.key(section)[0], []).append(f"  {key}: {written}{newline}")
        else:
            tail = added.setdefault(len(lines) - 1, [])
            if not any(line == f"{section}:{newline}" for line in tail):
                tail.append(f"{section}:{newline}")
            tail.append(f"  {key}: {written}{newline}")
    out = []
    for row, line in enumerate(lines):
        out.append(line)
        out += added.get(row, [])
    written_text = "".join(out)
    _checked(
        written_text, filename, "would not be a valid config with the new values; left as it is"
    )
    edited = _positions(written_text, filename)
    for path, value in changes.items():
        section, key = path.split(".")
        if edited[section][key] != value:  # a value written where it was not meant to be
            raise TuneError(f"{filename}: cannot edit {path} keeping the layout; left as it is")
    return written_text


def _positions(text: str, filename: str) -> CommentedMap:
    """The document as ruamel.yaml's round trip reads it: values with their line and column."""
    try:
        document = YAML().load(text)
    except YAMLError as error:  # what the config's own reader took, but this one does not
        raise TuneError(f"{filename}: cannot edit it keeping its layout: {error}") from None
    return document if isinstance(document, CommentedMap) else CommentedMap()


def _scalar(value: float | str) -> str:
    """A value as YAML writes it: a number's shortest exact form, a text double-quoted."""
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)
    return repr(float(value)) if isinstance(value, float) else str(value)


def _with_scalar(line: str, column: int, written: str) -> str:
    """`line` with the scalar that starts at `column` replaced by `written`; a comment after
    it, and the spaces before that comment, stay."""
    rest = line[column:]
    if rest[:1] in ('"', "'"):
        quote, at = rest[0], 1
        while at < len(rest):
            if rest[at] == "\\" and quote == '"':
                at += 2
                continue
            if rest[at] == quote:
                if quote == "'" and rest[at + 1 : at + 2] == "'":
                    at += 2
                    continue
                break
            at += 1
        end = at + 1
    else:
        comment = re.search(r"\s#", rest)
        body = rest[: comment.start()] if comment else rest
        end = len(body.rstrip(" \t\r\n"))
    return line[:column] + written + rest[end:]


def _last_line(lines: list[str], document: CommentedMap, section: str) -> int:
    """The last line that belongs to `section`: before the next section, its comments and
    blank lines aside (they introduce that section)."""
    sections = list(document)
    following = sections[sections.index(section) + 1 :]
    row = document.lc.key(following[0])[0] - 1 if following else len(lines) - 1
    while row > 0 and (not lines[row].strip() or lines[row].lstrip().startswith("#")):
        row -= 1
    return row


def write_tuned(path: Path, tuned: Tuned) -> str:
    """Write `tuned`'s recommended settings into the config file; a poor fit is not written."""
    if tuned.confidence != "good":
        raise TuneError(f"{path} left as it is: the fit is {tuned.confidence}")
    changes: dict[str, float | str] = dict(tuned.recommended)
    if "control.model_litres" not in changes:  # a log without the config's litres
        try:
            changes["control.model_litres"] = read.load(path).tun.litres
        except config_module.ConfigError as error:
            raise TuneError(f"{path} left as it is: {error}") from None
    return write_config(path, changes)


def write_config(path: Path, changes: Mapping[str, float | str]) -> str:
    """Write `changes` into the config file at `path` atomically; the unified diff ("" if none).

    The file keeps its permission bits, owner and group; a running daemon sees a new file,
    as after any edit. A file whose mode forbids writing it (0444) is refused, not replaced:
    read-only is someone's decision, and a rename would go round it.
    """
    path = path.resolve()
    try:
        with path.open(encoding="utf-8", newline="") as file:  # its own line ends, kept
            text = file.read()
        original = path.stat()
    except (OSError, UnicodeDecodeError) as error:
        raise TuneError(f"{path}: cannot read the config file: {error}") from None
    written = updated_config(text, str(path), changes)
    diff = "".join(
        difflib.unified_diff(
            text.splitlines(keepends=True), written.splitlines(keepends=True), str(path), str(path)
        )
    )
    locked = read_only(original)
    if diff and locked is not None:
        raise TuneError(
            f"{path}: the config file is read-only ({locked}): nothing written; make it "
            "writable (chmod u+w) to let tune write it, or leave out --write"
        )
    if diff:
        try:
            write_atomically(path, written, like=original)
        except OSError as error:
            raise TuneError(f"{path}: cannot write the config file: {error}") from None
    return diff


def _checked(text: str, filename: str, what: str) -> None:
    try:
        read.parse_document(text, filename)
    except config_module.ConfigError as error:
        problems = str(error).replace("\n", "; ")
        raise TuneError(f"{filename} {what}: {problems}") from None
