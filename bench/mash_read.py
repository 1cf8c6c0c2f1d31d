"""The read path with the mash's and the coil outlet's sensors beside the HLT's: what each
read (`Daemon._on_read`, once a second) costs the loop in CPU, with one sensor and with three.

Runs the real loop on the virtual clock against the simulated tun for a simulated hour per
row, each sensor the real driver on its fake at the OS boundary (sim/sensors.py): the HLT's
LM92 alone; with LM92s at 0x49 and 0x4A for the mash and the coil outlet; with a MAX31865
for the mash and a DS18B20 for the coil outlet. The fakes answer at once: the I2C and SPI
transfers' own time on a Pi is not in these figures, only the Python each read runs. The
simulator converts a DS18B20 in the loop's thread (a file written and read in a temporary
w1 tree), where on a Pi its reader thread does: that row counts more than a Pi's loop pays.

    uv run python bench/mash_read.py [--seconds 3600] [--write]
"""

from __future__ import annotations

import argparse
import dataclasses
import time

from hermsd.config import schema as config_module
from hermsd.config.schema import RoleSensorConfig
from hermsd.runtime.assemble import assemble
from hermsd.runtime.scheduler import percentile
from hermsd.sim.clock import VirtualClock
from hermsd.sim.sensors import fake_sensor
from hermsd.sim.world import build_world

MASH_C = 64.8  # what the mash's and the coil's fakes convert (a resting mash)
ROWS: dict[str, tuple[RoleSensorConfig | None, RoleSensorConfig | None]] = {
    "HLT alone (LM92)": (None, None),
    "+ mash LM92, coil LM92": (
        RoleSensorConfig(kind="lm92", address=0x49),
        RoleSensorConfig(kind="lm92", address=0x4A),
    ),
    "+ mash MAX31865, coil DS18B20": (
        RoleSensorConfig(kind="max31865", bus=0),
        RoleSensorConfig(kind="ds18b20", id="28-000000000002"),
    ),
}


def measure(
    mash: RoleSensorConfig | None, coil: RoleSensorConfig | None, seconds: float
) -> dict[str, float]:
    """`_on_read`'s CPU time per call (µs) over `seconds` of simulated time."""
    base = config_module.DEFAULT
    config = dataclasses.replace(
        base,
        output=dataclasses.replace(base.output, backend="sim"),
        mash_sensor=mash or RoleSensorConfig(),
        coil_sensor=coil or RoleSensorConfig(),
    )
    clock = VirtualClock()
    hlt = dataclasses.replace(
        config, mash_sensor=RoleSensorConfig(), coil_sensor=RoleSensorConfig()
    )
    world = build_world(hlt, clock, {"model": "foptd", "start_c": 66.0})  # the tun alone
    roles = [
        fake_sensor(role, clock.monotonic, lambda: MASH_C, clock.advance)[0]
        if role is not None
        else None
        for role in (mash, coil)
    ]
    daemon = assemble(
        config,
        clock,
        world.sensor,
        world.outputs,
        mash_sensor=roles[0],
        coil_sensor=roles[1],
    )
    samples: list[float] = []
    read = daemon._on_read

    def timed(deadline: float, now: float) -> None:
        begun = time.thread_time()
        read(deadline, now)
        samples.append(time.thread_time() - begun)

    daemon._on_read = timed  # type: ignore[method-assign]
    with daemon:
        daemon.start()
        daemon.run(until=clock.monotonic() + seconds)
    samples.sort()
    return {
        "reads": len(samples),
        "p50_us": percentile(samples, 50) * 1e6,
        "p99_us": percentile(samples, 99) * 1e6,
        "mean_us": sum(samples) / len(samples) * 1e6,
    }


def _table(rows: dict[str, dict[str, float]]) -> str:
    lines = [
        "| sensors | reads | per read p50 µs | p99 µs | mean µs |",
        "|---|---|---|---|---|",
    ]
    for name, row in rows.items():
        lines.append(
            f"| {name} | {row['reads']:.0f} | {row['p50_us']:.0f} | {row['p99_us']:.0f} | "
            f"{row['mean_us']:.0f} |"
        )
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=3600.0)
    parser.add_argument("--write", action="store_true", help="update bench/RESULTS.md")
    args = parser.parse_args()
    rows = {name: measure(*roles, args.seconds) for name, roles in ROWS.items()}
    table = _table(rows)
    print(table)
    if args.write:
        import sections  # bench/sections.py, beside this file

        text = (
            f"A simulated {args.seconds:.0f} s per row on the virtual clock: `Daemon._on_read` "
            "(once a second: the HLT's read and the supervisor's checks, then each sensor "
            "beside it), its thread's CPU time per call. The fakes answer at once: the I2C and "
            "SPI transfers' time on a Pi is not in it, only the Python a read runs. The "
            "simulator converts the DS18B20 in the loop's thread (a file written and read in "
            "a temporary w1 tree); on a Pi its reader thread does, and the loop's read takes "
            "the latest conversion: that row counts more than a Pi's loop pays.\n\n" + table
        )
        sections.write("## Mash side: the read path with three sensors", text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
