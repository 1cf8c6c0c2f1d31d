"""The LM92 word format against the datasheet, and the driver against the fake chip and bus."""

from __future__ import annotations

import errno
import math
from collections.abc import Callable, Sequence

import pytest
from hypothesis import given
from hypothesis import strategies as st

import hermsd.hardware.lm92
from hermsd.hardware.lm92 import (
    LM92,
    Reading,
    SensorError,
    WrongChipError,
    decode_temperature,
    encode_temperature,
    open_bus,
)
from hermsd.sim.bus import FakeLM92, FakeSMBus
from hermsd.sim.clock import VirtualClock

# Words worked out by hand from the datasheet format: steps = °C / 0.0625, written as 13-bit
# two's complement (negative: 8192 + steps) in D15..D3, i.e. word = that << 3.
#   +150     ->  2400 = 0x960  -> 0x4B00        +125 -> 2000 = 0x7D0 -> 0x3E80
#   +25      ->   400 = 0x190  -> 0x0C80        +0.0625 -> 1 -> 0x0008
#   0        ->     0          -> 0x0000        -0.0625 -> 8191 = 0x1FFF -> 0xFFF8
#   -25      ->  8192 - 400 = 7792 = 0x1E70 -> 0xF380
#   -55      ->  8192 - 880 = 7312 = 0x1C90 -> 0xE480
DATASHEET_WORDS = [
    (150.0, 0x4B00),
    (125.0, 0x3E80),
    (25.0, 0x0C80),
    (0.0625, 0x0008),
    (0.0, 0x0000),
    (-0.0625, 0xFFF8),
    (-25.0, 0xF380),
    (-55.0, 0xE480),
]


@pytest.mark.parametrize(("celsius", "word"), DATASHEET_WORDS)
def test_decode_matches_the_datasheet(celsius: float, word: int) -> None:
    assert decode_temperature(word) == celsius


@pytest.mark.parametrize(("celsius", "word"), DATASHEET_WORDS)
@pytest.mark.parametrize("status", [0b001, 0b010, 0b100, 0b111])
def test_decode_ignores_the_status_bits(celsius: float, word: int, status: int) -> None:
    assert decode_temperature(word | status) == celsius


@pytest.mark.parametrize(("celsius", "word"), DATASHEET_WORDS)
def test_encode_matches_the_datasheet(celsius: float, word: int) -> None:
    assert encode_temperature(celsius) == word


def test_decode_covers_the_whole_13_bit_span() -> None:
    # 0x7FF8: largest positive, 4095 steps = 255.9375 °C; 0x8000: -4096 steps = -256 °C.
    assert decode_temperature(0x7FF8) == 255.9375
    assert decode_temperature(0x8000) == -256.0


@pytest.mark.parametrize(
    ("celsius", "word"),
    [
        (25.03, 0x0C80),  # 400.48 steps -> 400
        (25.04, 0x0C88),  # 400.64 steps -> 401
        (25.03125, 0x0C80),  # 400.5 steps, a tie -> the even 400
        (-0.03, 0x0000),  # -0.48 steps -> 0, not a negative zero word
        (-24.97, 0xF380),  # -399.52 steps -> -400
        (149.99, 0x4B00),  # 2399.84 steps -> 2400, still in range
    ],
)
def test_encode_rounds_to_the_nearest_step(celsius: float, word: int) -> None:
    assert encode_temperature(celsius) == word


@pytest.mark.parametrize("word", [-1, 0x10000])
def test_decode_refuses_words_that_are_not_16_bit(word: int) -> None:
    with pytest.raises(ValueError, match="16 bits"):
        decode_temperature(word)


@pytest.mark.parametrize("celsius", [150.0625, -55.0625, 1e9, math.nan, math.inf, -math.inf])
def test_encode_refuses_what_the_chip_cannot_hold(celsius: float) -> None:
    with pytest.raises(ValueError, match=r"-55\.\.150"):
        encode_temperature(celsius)


@given(st.integers(min_value=-880, max_value=2400))
def test_decode_of_encode_is_exact_on_the_grid(steps: int) -> None:
    celsius = steps / 16  # exact in binary floating point
    assert decode_temperature(encode_temperature(celsius)) == celsius


@given(st.integers(min_value=-880, max_value=2400), st.integers(min_value=0, max_value=7))
def test_encode_of_decode_gives_the_word_back(steps: int, status: int) -> None:
    word = (steps % 8192) << 3  # 13-bit two's complement by modular arithmetic
    assert encode_temperature(decode_temperature(word | status)) == word


@given(st.floats(min_value=-55.0, max_value=150.0))
def test_encode_is_within_half_a_step(celsius: float) -> None:
    assert abs(decode_temperature(encode_temperature(celsius)) - celsius) <= 0.03125


class Water:
    """A temperature the test sets by hand, read by the fake chip."""

    def __init__(self, celsius: float = 20.0) -> None:
        self.celsius = celsius

    def __call__(self) -> float:
        return self.celsius


def make_sensor(water: Water, address: int = 0x48) -> tuple[LM92, FakeLM92, FakeSMBus]:
    chip = FakeLM92(water)
    bus = FakeSMBus()
    bus.attach(address, chip)
    return LM92(bus, address, bus_name="sim"), chip, bus


def test_read_gives_the_temperature_the_word_and_the_flags() -> None:
    water = Water(66.5)
    sensor, _, _ = make_sensor(water)
    # 66.5 °C = 1064 steps = 0x428 -> 0x2140; above T_HIGH (64 °C) -> D1 set -> 0x2142.
    assert sensor.read() == Reading(66.5, 0x2142, crit=False, high=True, low=False)


def test_flags_follow_the_limits_with_hysteresis() -> None:
    water = Water()
    sensor, _, _ = make_sensor(water)
    # Power-up limits: T_CRIT 80, T_HIGH 64, T_LOW 10, T_HYST 2 °C.
    walk = [
        (80.0, (True, True, False)),  # T_CRIT sets at >= 80
        (78.0, (True, True, False)),  # and stays down to 80 - 2
        (77.9375, (False, True, False)),  # clears below 78
        (79.9375, (False, True, False)),  # does not set again below 80
        (62.0, (False, True, False)),  # T_HIGH holds down to 64 - 2
        (61.9375, (False, False, False)),
        (9.9375, (False, False, True)),  # T_LOW sets below 10
        (12.0, (False, False, True)),  # and holds up to 10 + 2
        (12.0625, (False, False, False)),  # clears above 12
    ]
    for celsius, flags in walk:
        water.celsius = celsius
        reading = sensor.read()
        assert (reading.crit, reading.high, reading.low) == flags, celsius


def test_identify_accepts_an_lm92() -> None:
    sensor, _, _ = make_sensor(Water())
    sensor.identify()


def test_identify_names_the_other_chip() -> None:
    sensor, chip, _ = make_sensor(Water())
    chip.set_fault("wrong_id", 0x0190)
    with pytest.raises(WrongChipError) as caught:
        sensor.identify()
    message = str(caught.value)
    for part in ("sim", "0x48", "0x0190", "0x8001"):
        assert part in message
    assert caught.value.errno is None


def test_identify_with_nothing_at_the_address_is_a_nack_not_a_wrong_chip() -> None:
    _, _, bus = make_sensor(Water())
    sensor = LM92(bus, 0x49, bus_name="sim")
    with pytest.raises(SensorError) as caught:
        sensor.identify()
    assert type(caught.value) is SensorError
    assert caught.value.errno == errno.EREMOTEIO
    assert (caught.value.bus, caught.value.address) == ("sim", 0x49)
    assert "0x49 on sim" in str(caught.value)
    assert "NACK" in str(caught.value)


def test_limits_start_at_the_datasheet_power_up_values() -> None:
    sensor, _, _ = make_sensor(Water())
    assert [sensor.limit(name) for name in ("hyst", "low", "high", "crit")] == [2, 10, 64, 80]


def test_limits_are_programmed_read_back_and_acted_on() -> None:
    water = Water(85.0)
    sensor, _, _ = make_sensor(water)
    assert sensor.read().crit
    sensor.set_limit("crit", 90.03)  # rounds to the 0.0625 grid: 1440.48 steps -> 90.0
    sensor.set_limit("hyst", 0.5)
    sensor.set_limit("low", -10.0)
    sensor.set_limit("high", 66.0625)
    assert sensor.limit("crit") == 90.0
    assert sensor.limit("hyst") == 0.5
    assert sensor.limit("low") == -10.0
    assert sensor.limit("high") == 66.0625
    water.celsius = 89.5  # T_CRIT, set at 85 under the old limit, holds down to 90 - 0.5
    assert sensor.read().crit
    water.celsius = 89.4375  # and clears below it
    assert not sensor.read().crit
    water.celsius = 90.0
    assert sensor.read().crit


@pytest.mark.parametrize(
    ("name", "celsius", "complaint"),
    [("crit", 151.0, "outside"), ("hyst", -1.0, "hysteresis"), ("max", 50.0, "unknown")],
)
def test_set_limit_refuses_bad_arguments(name: str, celsius: float, complaint: str) -> None:
    sensor, _, _ = make_sensor(Water())
    with pytest.raises(ValueError, match=complaint):
        sensor.set_limit(name, celsius)  # type: ignore[arg-type]
    assert sensor.limit("crit") == 80.0


class IgnoresWrites:
    """A chip that acknowledges writes and keeps its old registers (a write-protected clone)."""

    def __init__(self, chip: FakeLM92) -> None:
        self._chip = chip

    def read(self, register: int, length: int) -> list[int]:
        return self._chip.read(register, length)

    def write(self, register: int, data: Sequence[int]) -> None:
        pass


def test_set_limit_fails_when_the_chip_does_not_keep_it() -> None:
    bus = FakeSMBus()
    bus.attach(0x4A, IgnoresWrites(FakeLM92(Water())))
    sensor = LM92(bus, 0x4A, bus_name="sim")
    with pytest.raises(
        SensorError, match=r"0x4a on sim: limit crit reads back 80 °C after writing 95 °C"
    ):
        sensor.set_limit("crit", 95.0)


def test_wake_leaves_shutdown_and_keeps_the_other_bits() -> None:
    water = Water(20.0)
    sensor, _, bus = make_sensor(water)
    sensor.read()
    bus.write_byte_data(0x48, 0x01, 0b1_1001)  # fault queue, INT polarity, shutdown
    water.celsius = 30.0
    assert sensor.read().celsius == 20.0  # in shutdown the register holds the last conversion
    sensor.wake()
    assert sensor.config() == 0b1_1000
    assert sensor.read().celsius == 30.0


def test_wake_fails_when_the_chip_stays_in_shutdown() -> None:
    chip = FakeLM92(Water())
    chip.write(0x01, [0x01])
    bus = FakeSMBus()
    bus.attach(0x48, IgnoresWrites(chip))
    sensor = LM92(bus, bus_name="sim")
    with pytest.raises(SensorError, match="still in shutdown"):
        sensor.wake()


def test_registers_repeat_every_eight_addresses() -> None:
    water = Water(25.0)
    sensor, _, bus = make_sensor(water)
    sensor.set_limit("crit", 70.0)
    # 70 °C = 1120 steps = 0x460 -> 0x2300; read through the aliases 0x0B and 0xF3.
    assert bus.read_i2c_block_data(0x48, 0x0B, 2) == [0x23, 0x00]
    assert bus.read_i2c_block_data(0x48, 0xF3, 2) == [0x23, 0x00]
    assert bus.read_i2c_block_data(0x48, 0x0F, 2) == [0x80, 0x01]
    assert bus.read_i2c_block_data(0x48, 0x08, 2) == [0x0C, 0x80]  # 25 °C


@pytest.mark.parametrize(
    ("fault", "code", "meaning"),
    [
        ("nack", errno.EREMOTEIO, "NACK"),
        ("gone", errno.EREMOTEIO, "NACK"),
        ("timeout", errno.ETIMEDOUT, "timeout"),
    ],
)
def test_bus_faults_surface_as_sensor_errors(fault: str, code: int, meaning: str) -> None:
    sensor, chip, _ = make_sensor(Water())
    chip.set_fault(fault)
    calls: list[Callable[[], object]] = [
        sensor.read,
        sensor.identify,
        sensor.config,
        sensor.wake,
        lambda: sensor.limit("crit"),
        lambda: sensor.set_limit("crit", 90.0),
    ]
    for call in calls:
        with pytest.raises(SensorError) as caught:
            call()
        error = caught.value
        assert (error.errno, error.bus, error.address) == (code, "sim", 0x48)
        assert isinstance(error.__cause__, OSError)
        assert error.__cause__.errno == code
        assert meaning in str(error)
        assert "LM92 at 0x48 on sim" in str(error)
    chip.set_fault("ok")
    assert sensor.read().celsius == 20.0


def test_a_stuck_sensor_repeats_itself() -> None:
    water = Water(20.0)
    sensor, chip, _ = make_sensor(water)
    water.celsius = 30.0
    chip.set_fault("stuck")
    water.celsius = 50.0
    assert [sensor.read().celsius for _ in range(3)] == [30.0, 30.0, 30.0]
    chip.set_fault("ok")
    assert sensor.read().celsius == 50.0


def test_a_spike_is_one_reading() -> None:
    water = Water(20.0)
    sensor, chip, _ = make_sensor(water)
    chip.set_fault("spike", 95.0)
    assert sensor.read() == Reading(95.0, 0x2F86, crit=True, high=True, low=False)
    # 95 °C = 1520 steps = 0x5F0 -> 0x2F80, with T_CRIT and T_HIGH set -> 0x2F86.
    assert sensor.read().celsius == 20.0


def test_a_slow_bus_takes_time_and_still_answers() -> None:
    clock = VirtualClock()
    chip = FakeLM92(lambda: 20.0, advance=clock.advance)
    bus = FakeSMBus()
    bus.attach(0x48, chip)
    sensor = LM92(bus, bus_name="sim")
    chip.set_fault("slow", 0.25)
    assert sensor.read().celsius == 20.0
    assert clock.monotonic() == 0.25
    sensor.set_limit("crit", 90.0)  # a write and a read-back
    assert clock.monotonic() == 0.75


class FailingBus:
    """A bus whose every transfer fails with one errno, as the kernel reports it."""

    def __init__(self, code: int) -> None:
        self._code = code

    def _fail(self) -> OSError:
        return OSError(self._code, "from the kernel")

    def read_i2c_block_data(self, i2c_addr: int, register: int, length: int) -> list[int]:
        raise self._fail()

    def write_i2c_block_data(self, i2c_addr: int, register: int, data: Sequence[int]) -> None:
        raise self._fail()

    def read_byte_data(self, i2c_addr: int, register: int) -> int:
        raise self._fail()

    def write_byte_data(self, i2c_addr: int, register: int, value: int) -> None:
        raise self._fail()


@pytest.mark.parametrize(
    ("code", "meaning"),
    [
        (errno.EIO, "I/O error (EIO, errno 5)"),
        (errno.ENXIO, "no such device or address (ENXIO, errno 6)"),
        (errno.EBUSY, "kernel driver"),
        (errno.EAGAIN, "errno 11"),
    ],
)
def test_every_errno_is_named(code: int, meaning: str) -> None:
    sensor = LM92(FailingBus(code), 0x4B, bus_name="/dev/i2c-1")
    with pytest.raises(SensorError) as caught:
        sensor.read()
    assert caught.value.errno == code
    assert str(caught.value).startswith(
        "LM92 at 0x4b on /dev/i2c-1: reading the temperature failed: "
    )
    assert meaning in str(caught.value)


class OneWordBus(FailingBus):
    """A bus that hands back one fixed word for every block read."""

    def __init__(self, word: int) -> None:
        super().__init__(errno.EIO)
        self._word = word

    def read_i2c_block_data(self, i2c_addr: int, register: int, length: int) -> list[int]:
        return [self._word >> 8, self._word & 0xFF]


@pytest.mark.parametrize("word", [0x4B08, 0x7FF8, 0xE478, 0x8000])
def test_a_word_outside_the_chip_range_is_an_error_not_a_reading(word: int) -> None:
    # 0x4B08 = 150.0625 °C and 0xE478 = -55.0625 °C, one step past each end; 0x7FF8 and
    # 0x8000 are the 13-bit extremes (255.9375 and -256 °C).
    sensor = LM92(OneWordBus(word), bus_name="sim")
    with pytest.raises(SensorError, match="outside the chip's range") as caught:
        sensor.read()
    assert caught.value.errno is None


@pytest.mark.parametrize("word", [0x4B07, 0xE487])
def test_the_ends_of_the_range_are_readings(word: int) -> None:
    reading = LM92(OneWordBus(word), bus_name="sim").read()
    assert reading.celsius in (150.0, -55.0)
    assert (reading.crit, reading.high, reading.low) == (True, True, True)


@pytest.mark.parametrize("address", [0x47, 0x4C, 0x90])
def test_only_lm92_addresses_are_accepted(address: int) -> None:
    with pytest.raises(ValueError, match=r"0x48\.\.0x4b"):
        LM92(FakeSMBus(), address)


def test_open_bus_explains_a_missing_bus() -> None:
    with pytest.raises(SensorError) as caught:
        open_bus(4093)
    assert str(caught.value) == (
        "no I2C bus /dev/i2c-4093: enable I2C (raspi-config) or check --bus"
    )
    assert (caught.value.errno, caught.value.bus, caught.value.address) == (
        errno.ENOENT,
        "/dev/i2c-4093",
        None,
    )
    assert isinstance(caught.value.__cause__, FileNotFoundError)


@pytest.mark.parametrize(
    ("exception", "message"),
    [
        (
            PermissionError(errno.EACCES, "Permission denied"),
            "permission denied on /dev/i2c-1: add the user to group i2c",
        ),
        (
            OSError(errno.ENOTTY, "Inappropriate ioctl for device"),
            "cannot open /dev/i2c-1: Inappropriate ioctl for device (errno 25)",
        ),
    ],
)
def test_open_bus_explains_other_refusals(
    monkeypatch: pytest.MonkeyPatch, exception: OSError, message: str
) -> None:
    def refuse(bus_number: int) -> None:
        raise exception

    monkeypatch.setattr(hermsd.hardware.lm92, "SMBus", refuse)
    with pytest.raises(SensorError) as caught:
        open_bus(1)
    assert str(caught.value) == message
    assert caught.value.errno == exception.errno
    assert caught.value.__cause__ is exception
