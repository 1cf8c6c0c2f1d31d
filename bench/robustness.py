"""hermsd and its peers on a family of brewers' tuns (a benchmark, not a test).

Each tun of `hermsd.sim.tuns.FAMILY` (30–150 L, 1.5–11 kW, UA ±50 %, dead time 30–300 s,
lid on and off, rooms at 5–30 °C, sensor noise sd 0.03 °C before the LM92's steps) runs its
brew day through the real daemon: ambient → 66 °C, a tenth of its volume of 15 °C water at
4 h, 6 h in all. hermsd runs with the shipped config (`config/hermsd.yaml`, only the tun's
litres and watts set to the truth): day 1 from an empty state directory, day 2 from what
day 1 left in it (what the controller learned, and any latched alarm). Beside it, on the
same tuns and the same config, the peers of bench/peers.py with seed 001's ITAE-load set
(what a brewer would copy). Every tun and controller runs on noise seeds 1…N: a goal must
hold on every seed, and "ahead of PIDHerms" is judged on each measure's mean over the
seeds, since one draw of the noise decides differences of a few parts per thousand.
Prints Markdown tables; `--write` puts them into bench/RESULTS.md.

    uv run --group bench python bench/robustness.py [--seeds 6] [--jobs 2] [--write]
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import multiprocessing
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path
from typing import Any

import sections  # bench/sections.py, beside this file
from peers import ITAE_LOAD, PEERS, controlled_by  # bench/peers.py, beside this file

from hermsd.config import read
from hermsd.config.schema import Config
from hermsd.sim import scenario
from hermsd.sim.tuns import FAMILY, NOISE_C, TunSpec

SHIPPED = Path(__file__).resolve().parents[1] / "config" / "hermsd.yaml"
SENSOR_KINDS = ("lm92", "ds18b20", "max31865")
KIND_WORDS = {
    "lm92": "the LM92 on I2C (the shipped sensor)",
    "ds18b20": (
        "a DS18B20 on 1-Wire in the tun's own well (its lag): the same 0.0625 °C steps, "
        "each read taking the conversion begun a read before (1 s old on the virtual clock; "
        "0.75–1.5 s from the reader thread on a Pi)"
    ),
    "max31865": (
        "a PT100 on a MAX31865 (reference 430 Ω, 3-wire): 15-bit codes of R/R_ref, about "
        "0.034 °C a code at 66 °C, through Callendar–Van Dusen"
    ),
}
DAY_1, DAY_2 = "hermsd day 1", "hermsd day 2"
CBPI = "CraftBeerPi PIDHerms"

# (summary key, limit, how the column shows it): each must hold for the row to pass.
DAY_2_GOALS = (
    ("heatup_overshoot_c", 0.1, "overshoot"),
    ("upset_overshoot_c", 0.1, "overshoot after water"),
    ("settle_ratio", 1.01, "settle"),
    ("recovery_ratio", 1.02, "recovery"),
    ("max_output_jump", 10.0, "jump"),
    ("ssr_edges_per_hour", 720.0, "edges/h"),
)
DAY_1_GOALS = (
    ("heatup_overshoot_c", 0.3, "overshoot"),
    ("upset_overshoot_c", 0.3, "overshoot after water"),
    ("last_hour_p2p_c", 0.1, "p-p last hour"),
)
AHEAD_KEYS = (
    ("heatup_overshoot_c", "overshoot"),
    ("upset_overshoot_c", "overshoot after water"),
    ("settle_ratio", "settle"),
    ("recovery_ratio", "recovery"),
    ("max_output_jump", "jump"),
)


def with_sensor(config: Config, kind: str) -> Config:
    """`config` reading the tun through a sensor of `kind` (a PT100 on a 430 Ω MAX31865)."""
    return dataclasses.replace(config, sensor=dataclasses.replace(config.sensor, kind=kind))


def brew_days(
    spec: TunSpec,
    seed: int = 1,
    *,
    peers: tuple[str, ...] = tuple(PEERS),
    keep_records: bool = False,
    kind: str = "lm92",
) -> dict[str, scenario.Result]:
    """Every controller's day on `spec` with noise seed `seed` and a sensor of `kind`:
    hermsd's two days, then each of `peers`."""
    config = with_sensor(spec.config(read.load(SHIPPED)), kind)
    return controller_days(spec.brew_day(seed=seed), config, peers=peers, keep_records=keep_records)


def controller_days(
    day: scenario.Scenario,
    config: Config,
    *,
    peers: tuple[str, ...] = tuple(PEERS),
    keep_records: bool = False,
) -> dict[str, scenario.Result]:
    """`day` under `config`: hermsd's day 1 from an empty state directory, its day 2 from
    what day 1 left there, then each of `peers` on the same config."""
    days = {}
    with tempfile.TemporaryDirectory(prefix="hermsd-state-") as state:
        for label in (DAY_1, DAY_2):
            days[label] = scenario.run(
                day, config, state_dir=Path(state), keep_records=keep_records
            )
    for peer in peers:
        with controlled_by(peer, ITAE_LOAD):
            days[peer] = scenario.run(day, config, keep_records=keep_records)
    return days


Summaries = dict[str, dict[str, Any]]
"""Each controller's day (its label) on one tun and seed: the day's summary."""


def _summaries(job: tuple[int, int, tuple[str, ...], str]) -> Summaries:
    index, seed, peers, kind = job
    return {
        label: result.summary
        for label, result in brew_days(FAMILY[index], seed, peers=peers, kind=kind).items()
    }


def run_seeds(
    indices: list[int],
    count: int,
    jobs: int,
    peers: tuple[str, ...] = tuple(PEERS),
    kind: str = "lm92",
) -> dict[tuple[int, int], Summaries]:
    """The days of `brew_days` on tuns `indices` of the family × noise seeds 1…`count`, on
    `jobs` processes, keyed by (tun's index, seed)."""
    work = [(index, seed) for index in indices for seed in range(1, count + 1)]
    jobs_work = [(index, seed, peers, kind) for index, seed in work]
    with multiprocessing.get_context("fork").Pool(jobs) as pool:
        found = pool.map(_summaries, jobs_work, chunksize=1)
    return dict(zip(work, found, strict=True))


Goals = tuple[tuple[str, float, str], ...]


def missed(summary: dict[str, Any], label: str, day_1: Goals = DAY_1_GOALS) -> list[str]:
    """The goals `summary` misses (day 2's for hermsd's day 2, `day_1` for every other)."""
    goals = DAY_2_GOALS if label == DAY_2 else day_1
    misses = [what for key, limit, what in goals if summary[key] is None or summary[key] > limit]
    if summary["held_in_band_pct"] != 100.0:
        misses.append("in band")
    if said_falsely(summary):
        misses.append("alarms")
    return misses


def said_falsely(summary: dict[str, Any], before: float = math.inf) -> list[str]:
    """The alarms and element warnings (docs/two-elements.md) raised before `before`: on a
    normal day, none is right (a warning stops asking the element it names)."""
    said = [(a["at_s"], a["kind"]) for a in summary["alarms"]]
    warned = summary.get("element_warnings", [])  # not in figures kept before it was logged
    said += [(w["at_s"], f"element {w['element']} warning") for w in warned]
    return [f"{kind} at {at:.0f} s" for at, kind in sorted(said) if at < before]


def behind(summary: dict[str, Any], cbpi: dict[str, Any]) -> list[str]:
    """Where hermsd is not ahead of CraftBeerPi's PIDHerms on the same tun."""
    return [
        what
        for key, what in AHEAD_KEYS
        if summary[key] is None or (cbpi[key] is not None and summary[key] >= cbpi[key])
    ]


def _same_day(day_1: dict[str, Any], day_2: dict[str, Any]) -> bool:
    """Whether day 2 held the tun exactly as day 1 did (its wall time aside)."""
    return {k: v for k, v in day_1.items() if k != "wall_s"} == {
        k: v for k, v in day_2.items() if k != "wall_s"
    }


def _cell(value: Any, digits: int) -> str:
    return "–" if value is None else f"{value:.{digits}f}"


def _values(days: list[dict[str, Any]], key: str) -> list[Any]:
    return [summary[key] for summary in days]


def worst(days: list[dict[str, Any]], key: str) -> float | None:
    """The worst of `key` over the seeds' `days` (None, which misses every goal, if any is)."""
    values = _values(days, key)
    if None in values:
        return None
    return float(min(values) if key == "held_in_band_pct" else max(values))


def means(days: list[dict[str, Any]]) -> dict[str, float | None]:
    """Each measure of `AHEAD_KEYS`, its mean over the seeds' `days` (None if any is None)."""
    found: dict[str, float | None] = {}
    for key, _ in AHEAD_KEYS:
        values = _values(days, key)
        found[key] = None if None in values else sum(values) / len(values)
    return found


def missed_on(days: list[dict[str, Any]], label: str) -> dict[str, int]:
    """On how many of the seeds' `days` each goal of `label`'s was missed, in the goals'
    order."""
    counts = Counter(what for summary in days for what in missed(summary, label))
    goals = DAY_2_GOALS if label == DAY_2 else DAY_1_GOALS
    order = [what for _, _, what in goals] + ["in band", "alarms"]
    return {what: counts[what] for what in order if counts[what]}


def ahead_on(days: list[dict[str, Any]], cbpis: list[dict[str, Any]]) -> Counter[str]:
    """On how many seeds `days` were ahead of PIDHerms' `cbpis`, measure by measure."""
    counts = Counter({what: 0 for _, what in AHEAD_KEYS})
    for summary, cbpi in zip(days, cbpis, strict=True):
        worse = behind(summary, cbpi)
        counts.update(what for _, what in AHEAD_KEYS if what not in worse)
    return counts


def _goals(misses: dict[str, int], n: int) -> str:
    if not misses:
        return f"yes, on {n} of {n} seeds"
    return "no: " + ", ".join(f"{what} on {k} of {n}" for what, k in misses.items())


def row(spec: TunSpec, label: str, s: dict[str, Any], verdict: str) -> str:
    alarms = ", ".join(f"{a['kind']} at {a['at_s']:.0f} s" for a in s["alarms"]) or "0"
    return (
        f"| {spec.name} | {label} | {_cell(s['heatup_overshoot_c'], 3)} "
        f"| {_cell(s['upset_overshoot_c'], 3)} | {_cell(s['settle_ratio'], 3)} "
        f"| {_cell(s['recovery_ratio'], 3)} | {_cell(s['max_output_jump'], 1)} "
        f"| {_cell(s['held_in_band_pct'], 2)} | {_cell(s['last_hour_p2p_c'], 3)} "
        f"| {_cell(s['ssr_edges_per_hour'], 0)} | {alarms} | {verdict} |"
    )


def worst_row(spec: TunSpec, label: str, days: list[dict[str, Any]]) -> str:
    """`label`'s worst over the seeds on `spec`, measure by measure, and its goals."""
    n = len(days)
    cells = " | ".join(
        _cell(worst(days, key), digits)
        for key, digits in (
            ("heatup_overshoot_c", 3),
            ("upset_overshoot_c", 3),
            ("settle_ratio", 4),
            ("recovery_ratio", 4),
            ("max_output_jump", 1),
            ("held_in_band_pct", 2),
            ("last_hour_p2p_c", 3),
            ("ssr_edges_per_hour", 0),
        )
    )
    alarmed = sum(bool(summary["alarms"]) for summary in days)
    return f"| {spec.name} | {label} | {cells} | {alarmed} | {_goals(missed_on(days, label), n)} |"


def _spread(values: list[Any], digits: int) -> str:
    """Mean (least–most) of `values`; the seeds without one (None) said, as they decide."""
    known = [float(v) for v in values if v is not None]
    if len(known) < len(values):
        return f"– (none on {len(values) - len(known)} of {len(values)})"
    mean = sum(known) / len(known)
    return f"{mean:.{digits}f} ({min(known):.{digits}f}–{max(known):.{digits}f})"


def ahead_rows(
    spec: TunSpec, days: list[dict[str, Any]], cbpis: list[dict[str, Any]], worse: list[str]
) -> str:
    """Day 2's and PIDHerms' ahead measures over the seeds, the verdict on their means
    (`worse`: where day 2's is not ahead), and on how many seeds day 2 was ahead on each."""
    digits = {"max_output_jump": 1}
    verdict = "ahead on every mean" if not worse else "not ahead on the mean of " + ", ".join(worse)
    lines = []
    for label, runs, last in ((DAY_2, days, verdict), (CBPI, cbpis, "")):
        cells = " | ".join(_spread(_values(runs, k), digits.get(k, 4)) for k, _ in AHEAD_KEYS)
        lines.append(f"| {spec.name} | {label} | {cells} | {last} |")
    counts = ahead_on(days, cbpis)
    cells = " | ".join(f"{counts[what]} of {len(days)}" for _, what in AHEAD_KEYS)
    lines.append(f"| {spec.name} | day 2 ahead on seeds | {cells} | |")
    return "\n".join(lines)


def family_table(minimums: dict[str, float | None], floors: dict[str, list[Any]]) -> str:
    """The tuns' parameters, how long full power takes each to the band, and the least
    recovery a controller acting on every reading can show (over the seeds: it depends on
    the duty day 2 runs when the water comes)."""
    lines = [
        "| tun | litres | element kW | UA W/K | transport delay s | sensor lag s | room °C "
        "| lid | full power to the band h | day 2's recovery floor ×min, seeds |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for spec in FAMILY:
        minimum = minimums[spec.name]
        known = [float(f) for f in floors[spec.name] if f is not None]
        floor = (
            f"{min(known):.3f}–{max(known):.3f}" if len(known) == len(floors[spec.name]) else "–"
        )
        lines.append(
            f"| {spec.name} | {spec.litres:g} | {spec.element_watts / 1000:g} "
            f"| {spec.ua_w_per_k:.1f} | {spec.transport_delay_s:g} | {spec.sensor_lag_s:g} "
            f"| {spec.ambient_c:g} | {'off' if spec.lid_off else 'on'} "
            f"| {_cell(None if minimum is None else minimum / 3600.0, 2)} | {floor} |"
        )
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help="update bench/RESULTS.md")
    parser.add_argument("--seeds", type=int, default=6, help="noise seeds 1…N (default 6)")
    parser.add_argument("--jobs", type=int, default=2, help="processes (default 2)")
    parser.add_argument(
        "--kind", choices=SENSOR_KINDS, default="lm92", help="the tun's sensor (default lm92)"
    )
    args = parser.parse_args()
    if args.seeds < 1:
        parser.error(f"--seeds {args.seeds}: give at least 1 (noise seeds 1…N)")
    n = args.seeds
    started = time.perf_counter()
    found = run_seeds(list(range(len(FAMILY))), n, args.jobs, kind=args.kind)
    wall = time.perf_counter() - started
    first = [
        "| tun | controller | overshoot °C | after water °C | settle ×min | recovery ×min "
        f"| jump % | in band % | p-p last h °C | edges/h | alarms | goals, seeds 1–{n} |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    worst_lines = [
        "| tun | controller | overshoot °C | after water °C | settle ×min | recovery ×min "
        "| jump % | in band % | p-p last h °C | edges/h | seeds with alarms | goals |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    ahead_lines = [
        "| tun | controller | overshoot °C | after water °C | settle ×min | recovery ×min "
        "| jump % | on the means |",
        "|---|---|---|---|---|---|---|---|",
    ]
    minimums: dict[str, float | None] = {}
    floors: dict[str, list[Any]] = {}
    counts = Counter({DAY_1: 0, DAY_2: 0, "ahead": 0})
    days_counts = Counter({DAY_1: 0, DAY_2: 0, "ahead": 0, "same": 0, "floor": 0})
    for index, spec in enumerate(FAMILY):
        seeds = [found[(index, seed)] for seed in range(1, n + 1)]
        by_label = {label: [days[label] for days in seeds] for label in seeds[0]}
        minimums[spec.name] = seeds[0][DAY_1]["physical_min_s"]
        floors[spec.name] = _values(by_label[DAY_2], "recovery_floor_ratio")
        cbpis = by_label[CBPI]
        worse = {label: behind(means(by_label[label]), means(cbpis)) for label in (DAY_1, DAY_2)}
        for label, days in by_label.items():
            verdict = _goals(missed_on(days, label), n)
            if label in worse:
                verdict += (
                    "; not ahead on the mean of " + ", ".join(worse[label])
                    if worse[label]
                    else "; ahead of PIDHerms on every mean"
                )
            first.append(row(spec, label, days[0], verdict))
        for label in (DAY_1, DAY_2):
            worst_lines.append(worst_row(spec, label, by_label[label]))
            counts[label] += not missed_on(by_label[label], label)
            days_counts[label] += sum(not missed(day, label) for day in by_label[label])
        ahead_lines.append(ahead_rows(spec, by_label[DAY_2], cbpis, worse[DAY_2]))
        counts["ahead"] += not worse[DAY_2]
        for day_1, day_2, cbpi in zip(by_label[DAY_1], by_label[DAY_2], cbpis, strict=True):
            days_counts["ahead"] += not behind(day_2, cbpi)
            days_counts["same"] += _same_day(day_1, day_2)
            floor, recovery = day_2["recovery_floor_ratio"], day_2["recovery_ratio"]
            days_counts["floor"] += None not in (floor, recovery) and recovery <= floor
    tuns, days_n = len(FAMILY), len(FAMILY) * n
    tally = (
        f"Over noise seeds 1–{n}: day 1 meets its goals on every seed on {counts[DAY_1]} of "
        f"{tuns} tuns ({days_counts[DAY_1]} of {days_n} days), day 2 on {counts[DAY_2]} of "
        f"{tuns} ({days_counts[DAY_2]} of {days_n} days); day 2 is ahead of PIDHerms on the "
        f"mean of every measure on {counts['ahead']} of {tuns} tuns (on every measure on "
        f"{days_counts['ahead']} of {days_n} days); day 2 repeats day 1 exactly on "
        f"{days_counts['same']} of {days_n} days (nothing carried over but latched alarms, if "
        f"any); day 2 recovers at its floor on {days_counts['floor']} of {days_n} days. "
        f"{days_n * (2 + len(PEERS))} brew days in {wall:.0f} s on {args.jobs} processes."
    )
    about = " ".join(
        [
            f"{KIND_WORDS[args.kind]}; the",
            "family of `hermsd/sim/tuns.py`, each on its brew day (room temperature → 66 °C, a",
            f"tenth of its volume of 15 °C water at 4 h, 6 h; sensor noise sd {NOISE_C} °C",
            "before the LM92's 0.0625 °C steps) through the real daemon, on each of the noise",
            f"seeds 1–{n} (the same tun and day, another draw of the sensor's noise). hermsd:",
            "the shipped config with the tun's true litres and watts; day 2 starts from the",
            "state directory day 1 of the same seed left (what the controller learned, and any",
            "latched alarm). The peers (bench/peers.py) run with seed 001's ITAE-load set",
            "(Kc 80.8, Ti 489 s, Td 44.9 s) on the same config. Measured on the sensor's",
            "temperature without its noise. Overshoot: above 66 °C in the heat-up; after water:",
            "above 66 °C after the dip. Settle and recovery: to within ±0.5 °C for good, over",
            "full power from the start and from the water on a copy of the tun. Jump: the",
            "largest output change between two periods while holding. In band: the time within",
            "±0.5 °C from first entering it, the recovery from the water aside. P-p: over the",
            "last hour, if all of it was held. Edges/h while holding. Goals, day 1 (and the",
            "peers): overshoot ≤ 0.3 °C both times, 100 % in band, p-p ≤ 0.1 °C, no alarm;",
            "day 2: overshoot ≤ 0.1 °C both times, settle ≤ ×1.01, recovery ≤ ×1.02, jump",
            "≤ 10 %, 100 % in band, ≤ 720 edges/h, no alarm; and ahead of PIDHerms on",
            "overshoot, settle, recovery and jump. A goal must hold on every seed: a tun meets",
            "its goals only if every seed's day does, and the tables say on how many seeds",
            "each goal was missed. Ahead of PIDHerms is judged measure by measure on the mean",
            f"over the {n} seeds (hermsd's day against PIDHerms' on the same tun and seeds),",
            "not on one draw: on some tuns the two differ by a few parts per thousand (a",
            "recovery a few seconds longer in half an hour), which one draw of the noise",
            "decides, e.g. whether the water comes while the SSR window has its on-time at its",
            "end or at its start; beside each mean, its least and most over the seeds and on",
            "how many seeds day 2 was ahead. First table: each controller's day on seed 1, its",
            "goals over every seed. Second: the worst over the seeds of each measure, hermsd's",
            "days. Third: the ahead measures, mean (least–most) over the seeds. Recovery floor:",
            "the least recovery a controller that acts on every reading (1 s) can show: nothing",
            "knows of the water before the first reading after it (0.5 s after it here), so",
            "until then the element runs at the duty day 2 decided before the water (its",
            "on-time first) and at full power from then on (a peer that happened to be at a",
            "higher duty then can come in under it); it depends on that duty, so on the seed.",
            "hermsd acts within the period once a reading lies at least 0.1875 °C (3 LSB) below",
            "the last period's PV after one at least 0.125 °C below it, and its controller",
            "answers it with full power or the fall is more than a period of full power adds",
            "back, so it recovers a reading or more behind this floor (bench/not_ahead.py shows",
            "where). Settle, recovery, their minimums and the floor are all crossing times: the",
            "minimums and the floor on a 1 s grid, settle and recovery between the two 5 s",
            "period samples that straddle the band's edge, both interpolated linearly",
            "(hermsd/metrics.py).",
            tally,
        ]
    )
    tables = [
        family_table(minimums, floors),
        "\n".join(first),
        f"Across seeds 1–{n}, hermsd's days: the worst of each measure over the seeds "
        "(least in band, most of every other).\n\n" + "\n".join(worst_lines),
        f"Across seeds 1–{n}, the measures day 2 must be ahead on: mean (least–most) over "
        "the seeds; the verdict on the means.\n\n" + "\n".join(ahead_lines),
    ]
    body = "\n\n".join(tables[1:])
    print(body + "\n\n" + tally)
    heading = "## Robustness: hermsd and its peers on twelve brewers' tuns"
    if args.kind != "lm92":
        heading = f"## Robustness with a {args.kind.upper()}: hermsd and its peers, same goals"
    text = about[0].upper() + about[1:] + "\n\n" + "\n\n".join(tables) + "\n"
    if args.write:
        sections.write(heading, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
