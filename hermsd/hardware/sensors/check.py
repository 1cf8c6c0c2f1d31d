"""`hermsd sensor --kind ds18b20|max31865`: the wiring check, one line a reading; a bad
reading is one line naming its trap and what to check, and the check reads on."""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from hermsd.hardware.lm92 import SensorError
from hermsd.hardware.sensors import ds18b20, max31865

SIMULATED_ID = "28-00000a1b2c3d"


def run(args: argparse.Namespace, wait: Callable[[float], None] = time.sleep) -> int:
    """0 when every reading was good, 1 when one was bad (each said on its line)."""
    if args.kind == "max31865" and args.decode is not None:
        return _decode(args)
    if args.kind == "ds18b20":
        return _ds18b20(args, wait)
    return _max31865(args, wait)


def _rounds(
    args: argparse.Namespace, wait: Callable[[float], None], once: Callable[[], bool]
) -> int:
    bad = False
    count = 0
    while args.count is None or count < args.count:
        if count:
            wait(1.0)
        bad = not once() or bad
        sys.stdout.flush()
        count += 1
    return 1 if bad else 0


def _ds18b20(args: argparse.Namespace, wait: Callable[[float], None]) -> int:
    if not args.simulate:
        return _ds18b20_under(args.w1_root, args, wait, None)
    from hermsd.sim.sensors import simulated_w1_tree

    with tempfile.TemporaryDirectory(prefix="hermsd-w1-") as directory:
        root, convert, advance = simulated_w1_tree(Path(directory), SIMULATED_ID)
        return _ds18b20_under(root, args, _paced(advance, wait), convert)


def _ds18b20_under(
    root: str | Path,
    args: argparse.Namespace,
    wait: Callable[[float], None],
    convert_all: Callable[[], None] | None,
) -> int:
    ids = [args.id] if args.id else ds18b20.find(root)
    if not ids:
        raise SensorError(
            f"no DS18B20 under {root}: enable 1-Wire (dtoverlay=w1-gpio in config.txt), "
            "check the 4.7 kΩ pull-up from DQ to 3.3 V, and the three wires",
            bus=str(root),
            address=None,
        )
    chips = [ds18b20.DS18B20(device_id, root) for device_id in ids]
    print(f"{len(chips)} DS18B20 under {'a simulated w1 tree' if args.simulate else root}")

    def once() -> bool:
        if convert_all is not None:
            convert_all()
        good = True
        for chip in chips:
            try:
                chip.identify()
                celsius, word = chip.convert()
            except SensorError as error:
                print(f"{chip.device_id}  bad reading: {error}")
                good = False
            else:
                print(f"{chip.device_id}  {celsius:8.4f} °C  raw 0x{word:04x}")
        return good

    return _rounds(args, wait, once)


def _driver(args: argparse.Namespace) -> max31865.MAX31865:
    where = f"MAX31865 on /dev/spidev{args.bus}.{args.device}"
    if args.simulate:
        from hermsd.sim.sensors import simulated_spi

        spi: max31865.SpiDevice = simulated_spi(args.r0, args.rref)
        where = "MAX31865 on a simulated SPI bus"
    else:
        spi = max31865.open_spi(args.bus, args.device)
    return max31865.MAX31865(
        spi, r0=args.r0, rref=args.rref, wires=args.wires, filter_hz=args.filter, where=where
    )


def _max31865(args: argparse.Namespace, wait: Callable[[float], None]) -> int:
    try:
        driver = _driver(args)
    except ValueError as error:
        raise SensorError(f"MAX31865: {error}", bus="spi", address=None) from None
    driver.identify()
    print(
        f"{driver.where}: PT{args.r0:g}, {args.wires}-wire, reference {args.rref:g} Ω, "
        f"{args.filter} Hz filter"
    )

    def once() -> bool:
        try:
            reading = driver.read()
        except SensorError as error:
            print(f"bad reading: {error}")
            return False
        ohms = reading.raw / max31865.CODE_FULL_SCALE * args.rref
        print(f"{reading.celsius:8.4f} °C  code {reading.raw} ({ohms:.4f} Ω)")
        return True

    return _rounds(args, wait, once)


def _decode(args: argparse.Namespace) -> int:
    rtd = args.decode
    setting = f"PT{args.r0:g}, reference {args.rref:g} Ω"
    if rtd & 1:
        print(
            f"{rtd:#06x}: the fault bit (D0) is set: the chip saw a fault, its fault status "
            "register (0x07) says which: run the check without --decode"
        )
        return 1
    try:
        celsius = max31865.decode(rtd, 0, args.r0, args.rref, "MAX31865")
    except SensorError as error:
        print(f"{rtd:#06x}: {error}")
        return 1
    ohms = (rtd >> 1) / max31865.CODE_FULL_SCALE * args.rref
    print(f"{rtd:#06x}: code {rtd >> 1}, {ohms:.4f} Ω, {celsius:.4f} °C ({setting})")
    return 0


def _paced(
    advance: Callable[[float], None], wait: Callable[[float], None]
) -> Callable[[float], None]:
    def paced(seconds: float) -> None:
        advance(seconds)
        wait(seconds)

    return paced
