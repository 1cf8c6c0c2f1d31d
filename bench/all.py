"""Re-measure every section of bench/RESULTS.md that a script writes, one command for all.

Each script runs in its own process, with the options its section was measured with and
`--write`, so each section is rewritten headed by this run's commit, date and command
(bench/sections.py). Prints each script's wall time and exit status; exits non-zero if any
failed (the others still run). Sections written by hand (no script writes them) are listed
by `--list` and kept as they are; `--check` fails if a section lacks its measured-at line.

    uv run python bench/all.py [--only NAME,...] [--list] [--check]

Run as root: the timing, socket and slow-disk benches measure a real-time loop as well.
Several take minutes (robustness, tuning, faults); the whole takes more than an hour.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import sections  # bench/sections.py, beside this file


@dataclass(frozen=True)
class Bench:
    """One script's run: its name for `--only`, its options, and the sections it writes."""

    name: str
    script: str
    options: tuple[str, ...]
    writes: tuple[str, ...]

    def argv(self) -> list[str]:
        return [sys.executable, f"bench/{self.script}", *self.options, "--write"]


# In the order of their sections in RESULTS.md, with the options each was measured with.
BENCHES = (
    Bench("control", "control.py", (), ("## Control: every algorithm on the seed-001 plant",)),
    Bench(
        "faults",
        "faults.py",
        (),
        (
            "## Faults: detection and heater-off latency",
            "## Faults on the family: fills the config does not know",
        ),
    ),
    Bench(
        "timing",
        "timing.py",
        ("--seconds", "250"),
        ("## Timing: the real loop on simulated hardware",),
    ),
    Bench("log", "log_bench.py", ("--hours", "24"), ("## Log: size, recorder CPU, read speed",)),
    Bench("replay", "replay.py", (), ("## Replay: a 24-hour log",)),
    Bench(
        "robustness",
        "robustness.py",
        ("--seeds", "6"),
        ("## Robustness: hermsd and its peers on twelve brewers' tuns",),
    ),
    Bench("midrange", "midrange.py", (), ("## Mid-ranging: the anti-windup seed, claim by claim",)),
    Bench(
        "tuning",
        "tuning.py",
        (),
        (
            "## Tuning from a brew day's log (`hermsd tune FILE`)",
            "## Tuning by a step test (`hermsd tune step`)",
            "## Tuning: the brew day after `tune --write`",
        ),
    ),
    Bench(
        "evaporation-fit",
        "evaporation_fit.py",
        (),
        ("## Tuning: an evaporation term in the step's fit",),
    ),
    Bench(
        "socket-load",
        "socket_load.py",
        ("--seconds", "120", "--rate", "1000"),
        ("## Control socket: the loop under 1,000 status requests a second",),
    ),
    Bench("two-element", "midrange.py", ("--tun",), ("## Mid-ranging: the two-element tun",)),
    Bench(
        "tuning-relay",
        "tuning.py",
        ("--relay",),
        ("## Tuning by a relay test (`hermsd tune relay`) and CraftBeerPi's autotune",),
    ),
    Bench(
        "program",
        "program.py",
        (),
        ("## Mash program: strike water ready by the time asked for",),
    ),
    Bench(
        "herms-cascade",
        "herms_cascade.py",
        (),
        ("## HERMS: the mash held by the outer loop, and its peers",),
    ),
    Bench(
        "herms-daemon",
        "herms_daemon.py",
        (),
        ("## HERMS in the daemon: the mash held by the outer loop",),
    ),
    Bench(
        "herms",
        "herms.py",
        ("--jobs", "2"),
        ("## HERMS family through the daemon: hermsd and its peers",),
    ),
    Bench(
        "herms-faults",
        "herms_faults.py",
        (),
        ("## HERMS faults: the supervisor with the pump running",),
    ),
    Bench(
        "herms-stuck",
        "herms_stuck.py",
        (),
        ("## HERMS: the no-flow sign (a stuck bed) and the mash after it",),
    ),
    Bench(
        "herms-pump",
        "herms_pump.py",
        (),
        ("## HERMS pump start: the HLT's drop, prepared and seen",),
    ),
    Bench(
        "slow-disk",
        "slow_disk.py",
        ("--seconds", "60", "--every", "10", "--stall", "2"),
        ("## Slow disk and tune fits: the loop with its saves and fits beside it",),
    ),
    Bench(
        "faults-two-elements",
        "faults.py",
        ("--two-elements",),
        ("## Faults on the family: two elements, fills the config does not know",),
    ),
    Bench(
        "soak", "soak.py", ("--days", "7"), ("## Soak: memory and loop CPU over days of logging",)
    ),
    *(
        Bench(
            f"robustness-{kind}",
            "robustness.py",
            ("--kind", kind, "--seeds", "2", "--jobs", "2"),
            (f"## Robustness with a {kind.upper()}: hermsd and its peers, same goals",),
        )
        for kind in ("ds18b20", "max31865")
    ),
    *(
        Bench(
            f"faults-{kind}",
            "faults.py",
            ("--kind", kind),
            (f"## Faults on the family with a {kind.upper()}: same goals",),
        )
        for kind in ("ds18b20", "max31865")
    ),
    Bench(
        "herms-plant",
        "herms_plant.py",
        (),
        ("## HERMS plant: the HLT's fall at pump start, and a day's cost",),
    ),
)

MEASURED = ("Measured at commit ", "Measured by hand at commit ")


def headed_sections(path: Path) -> dict[str, str]:
    """Each `## ` heading of the file and the first non-empty line under it."""
    found: dict[str, str] = {}
    heading = None
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.startswith("## "):
            heading = line
            found[heading] = ""
        elif heading is not None and not found[heading] and line.strip():
            found[heading] = line
    return found


def problems(path: Path) -> list[str]:
    """Sections without their measured-at line, and scripts' sections missing from the file."""
    found = headed_sections(path)
    missing = [f"{b.script}: no section {h!r}" for b in BENCHES for h in b.writes if h not in found]
    unheaded = [
        f"{h!r}: its first line does not say where it was measured"
        for h, first in found.items()
        if not first.startswith(MEASURED)
    ]
    return missing + unheaded


def listing(path: Path) -> str:
    written = {h for b in BENCHES for h in b.writes}
    lines = [f"{b.name}: {' '.join(b.argv()[1:])}" for b in BENCHES]
    lines += ["", "written by hand (not run):"]
    lines += [f"  {h[3:]}" for h in headed_sections(path) if h not in written]
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", metavar="NAME,...", help="run these benches only")
    parser.add_argument("--list", action="store_true", help="list the benches and stop")
    parser.add_argument(
        "--check", action="store_true", help="check every section's measured-at line and stop"
    )
    args = parser.parse_args()
    if args.list:
        print(listing(sections.RESULTS))
        return 0
    if args.check:
        found = problems(sections.RESULTS)
        print("\n".join(found) or "every section says where it was measured")
        return 1 if found else 0
    chosen = list(BENCHES)
    if args.only is not None:
        names = [n.strip() for n in args.only.split(",") if n.strip()]
        unknown = sorted(set(names) - {b.name for b in BENCHES})
        if unknown:
            parser.error(
                f"--only: no bench named {', '.join(unknown)}; "
                f"the benches: {', '.join(b.name for b in BENCHES)}"
            )
        chosen = [b for b in BENCHES if b.name in names]
    failed = []
    for bench in chosen:
        print(f"== {bench.name}: {' '.join(bench.argv()[1:])}", flush=True)
        started = time.perf_counter()
        status = subprocess.run(bench.argv(), cwd=sections.REPOSITORY, check=False).returncode
        wall = time.perf_counter() - started
        print(f"== {bench.name}: exit status {status} after {wall:.0f} s", flush=True)
        if status != 0:
            failed.append(bench.name)
    print(
        f"{len(chosen) - len(failed)} of {len(chosen)} benches ran; failed: "
        + (", ".join(failed) or "none")
    )
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
