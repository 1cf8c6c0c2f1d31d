"""Commissioning: the tun's model and the settings that follow from it.

- `table`: Table 1 of the PID calculus document (seed 001) for a model given by hand, printed
  as its Table 2 prints it.
- `from_log`: the model fitted to an ordinary brew day's logs (hermsd.identify), how sure the
  fit is, Table 1 for it, and the settings it recommends for the config file.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from decimal import ROUND_HALF_UP, Decimal
from typing import Any

from hermsd import pid

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
        return pid.table1(K=self.K, tau=self.tau, theta=self.theta, a_star=self.a_star)


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
    return Model(values["K"], values["tau"], values["theta"], a_star, given)


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
