"""`hermsd sensor` and `hermsd safe-off`: the hardware without the loop, a wiring check and
every output driven off."""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

from hermsd.cli.common import (
    DEFAULT_CONFIG,
)
from hermsd.config import read
from hermsd.hardware.lm92 import LM92, open_bus
from hermsd.hardware.ssr import open_hardware_switch

if TYPE_CHECKING:
    pass


def cmd_sensor(args: argparse.Namespace) -> int:
    wait: Callable[[float], None] = time.sleep
    if args.kind != "lm92":
        from hermsd.hardware.sensors import check

        args.bus = 0 if args.bus is None else args.bus
        return check.run(args, wait)
    args.bus = 1 if args.bus is None else args.bus
    if args.simulate:
        from hermsd.sim.world import simulated_sensor

        sensor, advance = simulated_sensor(args.address)

        def paced(seconds: float) -> None:
            """The simulated tun's time moves on, at the wall clock's pace: a reading a
            second, as from the real sensor (a brewer reads them; a test need not wait)."""
            advance(seconds)
            time.sleep(seconds)

        wait = paced
    else:
        sensor = LM92(open_bus(args.bus), args.address, bus_name=f"/dev/i2c-{args.bus}")
    sensor.identify()
    where = "simulated bus" if args.simulate else f"/dev/i2c-{args.bus}"
    print(f"LM92 found at {args.address:#04x} on {where}")
    count = 0
    while args.count is None or count < args.count:
        if count:
            wait(1.0)
        reading = sensor.read()
        flags = [
            name
            for name, on in (("CRIT", reading.crit), ("HIGH", reading.high), ("LOW", reading.low))
            if on
        ]
        print(f"{reading.celsius:8.4f} °C  raw 0x{reading.raw:04x}  {' '.join(flags)}".rstrip())
        sys.stdout.flush()
        count += 1
    return 0


def cmd_safe_off(args: argparse.Namespace) -> int:
    """Every output the config file names, off; exit 1 unless all of them are known to be off.

    The file is read as far as it can be (`config.load_outputs`), so a bad edit, the likely
    reason the daemon just stopped, cannot keep the element on.
    """
    from hermsd.hardware.safe_off import switch_off

    found = read.load_outputs(args.config or DEFAULT_CONFIG)
    report = switch_off(found, open_hardware_switch)
    for line in report.switched:
        print(line)
    for line in report.notes + report.failures:
        print(f"hermsd safe-off: {line}", file=sys.stderr)
    if report.failures:
        print("hermsd safe-off: not every output is known to be off", file=sys.stderr)
        return 1
    return 0
