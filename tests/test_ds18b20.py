"""DS18B20 through the w1 sysfs files: hand-derived scratchpads and every trap as a fault."""

from __future__ import annotations

import threading
from pathlib import Path

import pytest

from hermsd.hardware.lm92 import Reading, SensorError
from hermsd.hardware.sensors.base import (
    CONVERSION_PACE_S,
    ClockedConversions,
    Conversion,
    ThreadedConversions,
)
from hermsd.hardware.sensors.ds18b20 import (
    DS18B20,
    DS18B20Sensor,
    Scratchpad,
    TrapError,
    crc8,
    decode_scratchpad,
    find,
    parse_w1_slave,
    word_celsius,
)
from hermsd.sim.w1 import FakeW1Tree, w1_slave_text

ID = "28-0316a2795bff"


def crc8_by_division(data: bytes) -> int:
    """Dallas/Maxim CRC-8 by long division, MSB first, independent of the driver's LSB-first
    shift register: the bytes go LSB first on the wire, so each is bit-reversed, divided by
    x^8 + x^5 + x^4 + 1 (0x131), and the remainder reversed back."""

    def reverse(byte: int) -> int:
        return int(f"{byte:08b}"[::-1], 2)

    bits = "".join(f"{reverse(b):08b}" for b in data) + "0" * 8
    value = int(bits, 2)
    poly = 0x131
    for shift in range(len(bits) - 9, -1, -1):
        if value >> (shift + 8) & 1:
            value ^= poly << shift
    return reverse(value & 0xFF)


# Maxim application note 27's ROM example: family 02, serial 0000 01B8 1C, CRC A2.
def test_crc_of_the_application_note_rom() -> None:
    rom = bytes([0x02, 0x1C, 0xB8, 0x01, 0x00, 0x00, 0x00])
    assert crc8_by_division(rom) == 0xA2
    assert crc8(rom) == 0xA2


# Scratchpads as a DS18B20 sends them: 23.125 °C, and the power-on state (datasheet: 85 °C,
# TH 4B, TL 46, config 7F, reserved FF 0C 10).
@pytest.mark.parametrize(
    ("hexes", "crc"), [("72 01 4b 46 7f ff 0e 10", 0x57), ("50 05 4b 46 7f ff 0c 10", 0x1C)]
)
def test_crc_of_scratchpads(hexes: str, crc: int) -> None:
    data = bytes.fromhex(hexes)
    assert crc8_by_division(data) == crc
    assert crc8(data) == crc
    assert crc8(data + bytes([crc])) == 0


# Datasheet table 1: temperature/data relationship.
@pytest.mark.parametrize(
    ("word", "celsius"),
    [
        (0x07D0, 125.0),
        (0x0191, 25.0625),
        (0x00A2, 10.125),
        (0x0008, 0.5),
        (0x0000, 0.0),
        (0xFFF8, -0.5),
        (0xFF5E, -10.125),
        (0xFE6F, -25.0625),
        (0xFC90, -55.0),
    ],
)
def test_datasheet_words(word: int, celsius: float) -> None:
    assert word_celsius(word) == celsius


def test_a_w1_slave_text_decodes_from_its_bytes() -> None:
    text = "72 01 4b 46 7f ff 0e 10 57 : crc=57 YES\n72 01 4b 46 7f ff 0e 10 57 t=23125\n"
    pad = parse_w1_slave(text)
    assert pad == Scratchpad(bytes.fromhex("72014b467fff0e1057"), True)
    assert decode_scratchpad(pad, "x") == (23.125, 0x0172)
    assert w1_slave_text(pad.data) == text  # the fake prints what the kernel prints


def pad_of(hexes: str, kernel_ok: bool = True) -> Scratchpad:
    return Scratchpad(bytes.fromhex(hexes), kernel_ok)


def with_crc(hexes: str) -> Scratchpad:
    data = bytes.fromhex(hexes)
    return Scratchpad(data + bytes([crc8_by_division(data)]), True)


@pytest.mark.parametrize(
    ("pad", "trap"),
    [
        (
            pad_of("72014b467fff0e1056"),
            "crc",
        ),  # one bit off in the CRC byte, whatever the kernel said
        (pad_of("72014b467fff0e1057", False), "crc"),  # the kernel said NO
        (pad_of("50054b467fff0c101c"), "power_on"),
        (pad_of("000000000000000000"), "zeros"),  # crc8 of eight zeros is 0: it passes
        (pad_of("ffffffffffffffffff", False), "ones"),
        (
            with_crc("ff074b467fff0110"),
            "marker",
        ),
        (
            with_crc("10f84b467fff0010"),
            "marker",
        ),
        (
            with_crc("70014b461fff1010"),
            "resolution",
        ),
    ],
)
def test_each_trap_is_a_fault(pad: Scratchpad, trap: str) -> None:
    with pytest.raises(TrapError) as caught:
        decode_scratchpad(pad, "DS18B20 x")
    assert caught.value.trap == trap


def test_crc_of_every_byte_and_of_every_byte_after_another() -> None:
    # every entry of the driver's table, alone and reached from a register that is not 0
    for value in range(256):
        assert crc8(bytes([value])) == crc8_by_division(bytes([value]))
        assert crc8(bytes([0xA5, value])) == crc8_by_division(bytes([0xA5, value]))


def test_the_all_zero_scratchpad_passes_its_crc() -> None:
    assert crc8_by_division(bytes(8)) == 0  # why the zeros need their own trap


def test_a_family_other_than_28_is_refused(tmp_path: Path) -> None:
    tree = FakeW1Tree(tmp_path)
    tree.add("10-000802b4a8c1", lambda: 20.0)
    with pytest.raises(TrapError, match="DS18S20") as caught:
        DS18B20("10-000802b4a8c1", tmp_path).identify()
    assert caught.value.trap == "family"


def test_find_lists_only_ds18b20s(tmp_path: Path) -> None:
    tree = FakeW1Tree(tmp_path)
    tree.add("28-00000b0c0d0e", lambda: 20.0)
    tree.add(ID, lambda: 20.0)
    tree.add("10-000802b4a8c1", lambda: 20.0)
    assert find(tmp_path) == ["28-00000b0c0d0e", ID]
    assert find(tmp_path / "absent") == []


def test_the_fake_quantises_to_a_sixteenth_and_the_driver_reads_it(tmp_path: Path) -> None:
    chip = FakeW1Tree(tmp_path).add(ID, lambda: 66.1)
    chip.convert()
    # 66.1 × 16 = 1057.6 → 1057 steps = 66.0625 °C, word 0x0421
    assert DS18B20(ID, tmp_path).convert() == (66.0625, 0x0421)


def test_the_temperature_file_when_there_is_no_w1_slave(tmp_path: Path) -> None:
    chip = FakeW1Tree(tmp_path).add(ID, lambda: -10.125)
    chip.convert()
    (tmp_path / ID / "w1_slave").unlink()
    assert (tmp_path / ID / "temperature").read_text() == "-10125\n"
    assert DS18B20(ID, tmp_path).convert() == (-10.125, 0xFF5E)
    (tmp_path / ID / "temperature").write_text("85000\n")
    with pytest.raises(TrapError, match="power-on"):
        DS18B20(ID, tmp_path).convert()
    (tmp_path / ID / "temperature").write_text("-127000\n")
    with pytest.raises(TrapError, match="marker"):
        DS18B20(ID, tmp_path).convert()


@pytest.mark.parametrize(
    ("fault", "trap"),
    [
        ("crc", "crc"),
        ("power_on", "power_on"),
        ("zeros", "zeros"),
        ("ones", "ones"),
        ("marker", "marker"),
        ("resolution", "resolution"),
    ],
)
def test_each_fake_fault_reaches_the_driver_as_its_trap(
    tmp_path: Path, fault: str, trap: str
) -> None:
    chip = FakeW1Tree(tmp_path).add(ID, lambda: 66.0)
    chip.set_fault(fault)
    chip.convert()
    with pytest.raises(TrapError) as caught:
        DS18B20(ID, tmp_path).convert()
    assert caught.value.trap == trap


def test_a_device_that_leaves_the_bus_is_a_fault_until_it_returns(tmp_path: Path) -> None:
    chip = FakeW1Tree(tmp_path).add(ID, lambda: 66.0)
    driver = DS18B20(ID, tmp_path)
    chip.set_fault("gone")
    with pytest.raises(SensorError, match="gone from the bus"):
        driver.identify()
    with pytest.raises(SensorError, match="gone from the bus"):
        driver.convert()
    chip.set_fault("ok")
    with pytest.raises(TrapError, match="power-on"):  # back, not yet converted
        driver.convert()
    chip.convert()
    assert driver.convert() == (66.0, 0x0420)


# 85.000 °C, the datasheet's power-on value (word 0x0550, the scratchpad 50 05 4b 46 7f ff 0c
# 10 1c), is a temperature too: believed within 2 °C of the last good reading, no further.
@pytest.mark.parametrize(
    ("previous", "power_on"),
    [(None, True), (66.0, True), (82.9375, True), (83.0, False), (84.9375, False), (85.0, False)],
)
def test_85_is_the_power_on_value_unless_the_reading_before_was_near_it(
    previous: float | None, power_on: bool
) -> None:
    pad = pad_of("50054b467fff0c101c")
    if power_on:
        with pytest.raises(TrapError) as caught:
            decode_scratchpad(pad, "DS18B20 x", previous)
        assert caught.value.trap == "power_on"
    else:
        assert decode_scratchpad(pad, "DS18B20 x", previous) == (85.0, 0x0550)


def test_an_hlt_heating_past_85_reads_85_on_its_way(tmp_path: Path) -> None:
    water = [84.0]
    chip = FakeW1Tree(tmp_path).add(ID, lambda: water[0])
    driver = DS18B20(ID, tmp_path)
    read = []
    for celsius in (84.0, 84.97, 85.0, 85.03, 85.1):
        water[0] = celsius
        chip.convert()
        read.append(driver.convert())
    # each truncated to 1/16 °C: 84.97 × 16 = 1359.5 → 1359, 85.03 × 16 = 1360.5 → 1360
    assert read == [
        (84.0, 0x0540),
        (84.9375, 0x054F),
        (85.0, 0x0550),
        (85.0, 0x0550),
        (85.0625, 0x0551),
    ]
    (tmp_path / ID / "w1_slave").unlink()  # the kernel's `temperature` file alone
    (tmp_path / ID / "temperature").write_text("85000\n")
    assert driver.convert() == (85.0, 0x0550)


def test_85_after_a_failed_read_or_from_far_away_is_the_power_on_value(tmp_path: Path) -> None:
    water = [84.5]
    chip = FakeW1Tree(tmp_path).add(ID, lambda: water[0])
    driver = DS18B20(ID, tmp_path)
    chip.convert()
    assert driver.convert() == (84.5, 0x0548)
    chip.set_fault("gone")  # unplugged near 85 °C
    with pytest.raises(SensorError, match="gone from the bus"):
        driver.convert()
    chip.set_fault("ok")
    with pytest.raises(TrapError, match="power-on"):  # back, powered up afresh: 85.000
        driver.convert()
    water[0] = 60.0
    chip.convert()
    assert driver.convert() == (60.0, 0x03C0)
    chip.set_fault("power_on")  # a supply dip at 60 °C
    chip.convert()
    with pytest.raises(TrapError, match="power-on"):
        driver.convert()


class Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def test_clocked_conversions_take_the_conversion_time_and_add_the_offset(tmp_path: Path) -> None:
    temperature = [20.0]
    chip = FakeW1Tree(tmp_path).add(ID, lambda: temperature[0])
    driver = DS18B20(ID, tmp_path)
    clock = Clock()

    def convert() -> tuple[float, int]:
        chip.convert()
        return driver.convert()

    sensor = DS18B20Sensor(
        driver,
        lambda c: ClockedConversions(c, clock, 0.75),
        clock,
        offset_c=-0.25,
        convert=convert,
    )
    temperature[0] = 30.0
    reading = sensor.read()  # the first, done as the reader started, of 20 °C
    assert (reading.celsius, reading.raw) == (19.75, 0x0140)
    clock.now = 0.75
    assert sensor.read().celsius == 19.75  # begun at 0 s, when it was 20 °C
    clock.now = 1.5
    assert sensor.read().celsius == 29.75
    clock.now = 4.5  # nothing read for 3 s: the next finishes only now
    assert sensor.read().celsius == 29.75
    sensor.close()


def test_the_loop_never_waits_for_a_threaded_conversion() -> None:
    release, second_began, stop = threading.Event(), threading.Event(), threading.Event()
    calls = []

    def convert() -> Reading:
        calls.append(1)
        if len(calls) == 1:
            release.wait()
            return Reading(21.5, 0x0158, False, False, False)
        second_began.set()  # the first is stored before the second begins
        stop.wait()
        raise SensorError("stopped", bus="test", address=None)

    conversions = ThreadedConversions(convert, lambda: 7.0, pause=lambda seconds: None)
    conversions.start()
    assert conversions.latest() is None  # taken while the thread is inside a conversion
    release.set()
    assert second_began.wait(timeout=10)
    latest = conversions.latest()
    assert latest == Conversion(Reading(21.5, 0x0158, False, False, False), None, 7.0)
    conversions.close()
    stop.set()


class Held:
    """Conversions whose reader stalled after one conversion done at 0.75 s."""

    def __init__(self, convert: object) -> None:
        self.latest_one: Conversion | None = Conversion(
            Reading(50.0, 0x0320, False, False, False), None, 0.75
        )

    def start(self) -> None: ...

    def close(self) -> None: ...

    def wait_first(self, timeout_s: float) -> None: ...

    def latest(self) -> Conversion | None:
        return self.latest_one


def test_no_conversion_yet_is_a_failed_read(tmp_path: Path) -> None:
    sensor = DS18B20Sensor(DS18B20(ID, tmp_path), Held, Clock())
    sensor._conversions.latest_one = None  # type: ignore[attr-defined]
    with pytest.raises(SensorError, match="no conversion finished yet"):
        sensor.read()


def test_a_stale_conversion_is_a_failed_read(tmp_path: Path) -> None:
    clock = Clock()
    sensor = DS18B20Sensor(DS18B20(ID, tmp_path), Held, clock, max_age_s=2.5)
    clock.now = 3.25
    assert sensor.read().celsius == 50.0
    clock.now = 3.3
    with pytest.raises(SensorError, match=r"2\.5 s old"):
        sensor.read()


def test_a_shorter_conversion_leaves_no_trace_of_the_longer_one(tmp_path: Path) -> None:
    celsius = [-10.125]
    chip = FakeW1Tree(tmp_path).add(ID, lambda: celsius[0])
    chip.convert()  # t=-10125
    celsius[0] = 0.5
    chip.convert()  # t=500: the files are written over in place, then cut to their length
    # 0.5 °C = 8 sixteenths: word 0x0008, the bytes 08 00 4b 46 7f ff 08 10 and their CRC
    data = bytes([0x08, 0x00, 0x4B, 0x46, 0x7F, 0xFF, 0x08, 0x10])
    pad = " ".join(f"{b:02x}" for b in data) + f" {crc8_by_division(data):02x}"
    crc = f"{crc8_by_division(data):02x}"
    assert (tmp_path / ID / "w1_slave").read_text() == f"{pad} : crc={crc} YES\n{pad} t=500\n"
    assert (tmp_path / ID / "temperature").read_text() == "500\n"
    assert DS18B20(ID, tmp_path).convert() == (0.5, 0x0008)


def test_a_device_that_fails_at_once_is_asked_again_at_the_conversions_pace() -> None:
    """Gone from the bus, a read fails at once: the reader waits out the rest of a
    conversion's time before the next, rather than spinning beside the control loop."""
    clock = [100.0]
    paused: list[float] = []

    def gone() -> Reading:
        clock[0] += 0.01  # the failed open takes 10 ms
        raise SensorError("gone from the bus", bus="test", address=None)

    def pause(seconds: float) -> None:
        paused.append(seconds)
        clock[0] += seconds
        if len(paused) == 3:
            conversions.close()

    conversions = ThreadedConversions(gone, lambda: clock[0], pause=pause)
    conversions._run()  # in this thread: three failed conversions, then closed
    assert paused == pytest.approx([CONVERSION_PACE_S - 0.01] * 3)
    latest = conversions.latest()
    assert latest is not None and latest.error is not None and latest.reading is None
