"""The fake bus and fake LM92 behave as smbus2, i2c-dev and the datasheet say, byte for byte."""

from __future__ import annotations

import errno
import inspect
import os
from collections.abc import Callable

import pytest
import smbus2

from hermsd.sim.bus import FakeLM92, FakeSMBus, Fault
from hermsd.sim.clock import VirtualClock

ADDRESS = 0x48


class Water:
    """A temperature the test sets by hand."""

    def __init__(self, celsius: float = 20.0) -> None:
        self.celsius = celsius

    def __call__(self) -> float:
        return self.celsius


def make_bus(water: Callable[[], float]) -> tuple[FakeSMBus, FakeLM92]:
    chip = FakeLM92(water)
    bus = FakeSMBus()
    bus.attach(ADDRESS, chip)
    return bus, chip


def word(bus: FakeSMBus, register: int) -> int:
    msb, lsb = bus.read_i2c_block_data(ADDRESS, register, 2)
    return msb << 8 | lsb


@pytest.mark.parametrize(
    "name",
    [
        "read_i2c_block_data",
        "write_i2c_block_data",
        "read_byte_data",
        "write_byte_data",
        "close",
        "__enter__",
        "__exit__",
    ],
)
def test_methods_have_smbus2_signatures(name: str) -> None:
    def shape(function: object) -> list[tuple[str, object, object]]:
        signature = inspect.signature(function)  # type: ignore[arg-type]
        return [(p.name, p.kind, p.default) for p in signature.parameters.values()]

    assert shape(getattr(FakeSMBus, name)) == shape(getattr(smbus2.SMBus, name))


def test_an_empty_address_nacks_like_i2c_dev() -> None:
    bus, _ = make_bus(Water())
    transfers: list[Callable[[], object]] = [
        lambda: bus.read_i2c_block_data(0x49, 0, 2),
        lambda: bus.write_i2c_block_data(0x49, 3, [0x28, 0x00]),
        lambda: bus.read_byte_data(0x49, 1),
        lambda: bus.write_byte_data(0x49, 1, 0),
    ]
    for transfer in transfers:
        with pytest.raises(OSError, match="Remote I/O error") as caught:
            transfer()
        assert caught.value.errno == errno.EREMOTEIO


def test_a_closed_bus_refuses_to_work() -> None:
    water = Water()
    with make_bus(water)[0] as bus:
        assert word(bus, 0x07) == 0x8001
    with pytest.raises(ValueError, match="after close"):
        word(bus, 0x07)


@pytest.mark.parametrize(
    ("transfer", "complaint"),
    [
        (lambda bus: bus.read_i2c_block_data(ADDRESS, 0, 0), "block length"),
        (lambda bus: bus.read_i2c_block_data(ADDRESS, 0, 33), "block length"),
        (lambda bus: bus.write_i2c_block_data(ADDRESS, 3, []), "block length"),
        (lambda bus: bus.read_i2c_block_data(ADDRESS, 0x100, 2), "byte"),
        (lambda bus: bus.write_byte_data(ADDRESS, 1, 0x100), "byte"),
        (lambda bus: bus.write_i2c_block_data(ADDRESS, 3, [0x28, -1]), "byte"),
        (lambda bus: bus.read_byte_data(0x80, 0), "7 bits"),
        (lambda bus: bus.attach(0x80, FakeLM92(Water())), "7 bits"),
        (lambda bus: bus.attach(ADDRESS, FakeLM92(Water())), "taken"),
    ],
)
def test_bad_arguments_are_refused(transfer: Callable[[FakeSMBus], object], complaint: str) -> None:
    bus, _ = make_bus(Water())
    with pytest.raises(ValueError, match=complaint):
        transfer(bus)


@pytest.mark.parametrize(
    ("celsius", "expected"),
    [
        # floor(°C / 0.0625) in 13-bit two's complement << 3, plus the flags of the
        # power-up limits (T_LOW 10 -> D0 below it; T_HIGH 64 -> D1; T_CRIT 80 -> D2).
        (25.0, 0x0C80),  # 400 steps exactly
        (25.06, 0x0C80),  # 400.96 steps truncates to 400, not 401
        (25.0625, 0x0C88),  # 401
        (-0.01, 0xFFF9),  # -0.16 -> -1 (toward -inf): 8191 << 3 = 0xFFF8, below T_LOW
        (-25.03, 0xF379),  # -400.48 -> -401: 7791 = 0x1E6F -> 0xF378, below T_LOW
        (149.99, 0x4AFE),  # 2399.84 -> 2399 = 0x95F -> 0x4AF8, T_CRIT and T_HIGH
        (150.03, 0x4B06),  # clamped at 150: 2400 = 0x960 -> 0x4B00
        (400.0, 0x4B06),
        (float("inf"), 0x4B06),
        (-55.0, 0xE481),  # -880: 7312 = 0x1C90 -> 0xE480, below T_LOW
        (-80.0, 0xE481),  # clamped at -55
    ],
)
def test_the_adc_truncates_toward_minus_infinity_and_clamps(celsius: float, expected: int) -> None:
    bus, _ = make_bus(Water(celsius))
    assert word(bus, 0x00) == expected


def test_a_nan_from_the_model_is_not_turned_into_a_word() -> None:
    bus, _ = make_bus(Water(float("nan")))
    with pytest.raises(ValueError, match="NaN"):
        word(bus, 0x00)


def test_flags_keep_their_state_inside_the_hysteresis_band() -> None:
    water = Water()
    bus, _ = make_bus(water)
    # Power-up limits T_CRIT 80, T_HIGH 64, T_LOW 10, T_HYST 2 °C; flags are D2 D1 D0.
    walk = [
        (20.0, 0b000),
        (64.0, 0b010),  # T_HIGH sets at >= 64
        (62.0, 0b010),  # holds down to 62
        (61.9375, 0b000),  # clears below 62
        (63.9375, 0b000),  # does not set again below 64
        (80.0, 0b110),
        (78.0, 0b110),
        (77.9375, 0b010),
        (79.9375, 0b010),
        (10.0, 0b000),  # T_LOW sets only below 10
        (9.9375, 0b001),
        (12.0, 0b001),  # holds up to 12
        (12.0625, 0b000),
        (11.0, 0b000),  # does not set again above 10
    ]
    for celsius, flags in walk:
        water.celsius = celsius
        assert word(bus, 0x00) & 0b111 == flags, celsius


def test_limits_are_kept_word_for_word_and_change_the_flags() -> None:
    water = Water(30.0)
    bus, _ = make_bus(water)
    bus.write_i2c_block_data(ADDRESS, 0x05, [0x0C, 0x80])  # T_HIGH = 25 °C
    bus.write_i2c_block_data(ADDRESS, 0x02, [0x00, 0x08])  # T_HYST = 0.0625 °C
    assert word(bus, 0x05) == 0x0C80
    assert word(bus, 0x02) == 0x0008
    assert word(bus, 0x00) == 0x0F02  # 30 °C = 480 steps = 0x1E0 -> 0x0F00, above T_HIGH
    water.celsius = 24.9375
    assert word(bus, 0x00) & 0b010 == 0b010  # holds down to 25 - 0.0625
    water.celsius = 24.875
    assert word(bus, 0x00) & 0b010 == 0  # clears below it


def test_power_up_registers() -> None:
    bus, _ = make_bus(Water())
    # T_HYST 2 °C = 32 steps -> 0x0100; T_CRIT 80 = 1280 -> 0x2800;
    # T_LOW 10 = 160 -> 0x0500; T_HIGH 64 = 1024 -> 0x2000.
    assert [word(bus, register) for register in (2, 3, 4, 5, 7)] == [
        0x0100,
        0x2800,
        0x0500,
        0x2000,
        0x8001,
    ]
    assert bus.read_byte_data(ADDRESS, 0x01) == 0


def test_register_addresses_repeat_every_eight() -> None:
    water = Water(25.0)
    bus, _ = make_bus(water)
    bus.write_i2c_block_data(ADDRESS, 0x1C, [0xF3, 0x80])  # T_LOW via 0x1C = 0x04 + 24
    assert word(bus, 0x04) == 0xF380
    bus.write_byte_data(ADDRESS, 0x09, 0x10)  # configuration via 0x09
    assert bus.read_byte_data(ADDRESS, 0x01) == 0x10
    assert bus.read_byte_data(ADDRESS, 0xF9) == 0x10
    assert word(bus, 0xFF) == 0x8001
    assert word(bus, 0x08) == word(bus, 0x00) == 0x0C80


def test_configuration_bits_7_to_5_read_zero() -> None:
    bus, _ = make_bus(Water())
    bus.write_byte_data(ADDRESS, 0x01, 0xFE)
    assert bus.read_byte_data(ADDRESS, 0x01) == 0x1E


def test_a_one_byte_read_of_a_word_register_gives_its_msb() -> None:
    bus, _ = make_bus(Water())
    assert bus.read_byte_data(ADDRESS, 0x07) == 0x80
    assert bus.read_i2c_block_data(ADDRESS, 0x03, 1) == [0x28]


@pytest.mark.parametrize(
    ("transfer", "complaint"),
    [
        (lambda bus: bus.read_i2c_block_data(ADDRESS, 0x01, 2), "1 byte"),
        (lambda bus: bus.read_i2c_block_data(ADDRESS, 0x00, 3), "undefined"),
        (lambda bus: bus.read_i2c_block_data(ADDRESS, 0x06, 2), "not defined"),
        (lambda bus: bus.write_i2c_block_data(ADDRESS, 0x00, [0, 0]), "not writable"),
        (lambda bus: bus.write_i2c_block_data(ADDRESS, 0x07, [0, 0]), "not writable"),
        (lambda bus: bus.write_i2c_block_data(ADDRESS, 0x06, [0, 0]), "not writable"),
        (lambda bus: bus.write_byte_data(ADDRESS, 0x03, 0x28), "2 bytes"),
        (lambda bus: bus.write_i2c_block_data(ADDRESS, 0x01, [0, 0]), "1 byte"),
    ],
)
def test_transfers_the_datasheet_leaves_undefined_are_refused(
    transfer: Callable[[FakeSMBus], object], complaint: str
) -> None:
    bus, _ = make_bus(Water())
    with pytest.raises(ValueError, match=complaint):
        transfer(bus)


def test_shutdown_holds_the_conversion_made_as_the_chip_stops() -> None:
    water = Water(20.0)
    bus, _ = make_bus(water)
    assert word(bus, 0x00) == 0x0A00  # 20 °C = 320 steps = 0x140 -> 0x0A00
    water.celsius = 30.0
    bus.write_byte_data(ADDRESS, 0x01, 0x01)
    water.celsius = 40.0
    assert word(bus, 0x00) == 0x0F00  # 30 °C, converted when shutdown began
    bus.write_byte_data(ADDRESS, 0x01, 0x00)
    assert word(bus, 0x00) == 0x1400  # 40 °C = 640 steps = 0x280 -> 0x1400


@pytest.mark.parametrize(
    ("fault", "code"),
    [("nack", errno.EREMOTEIO), ("gone", errno.EREMOTEIO), ("timeout", errno.ETIMEDOUT)],
)
def test_failing_transfers_raise_the_kernel_errno(fault: str, code: int) -> None:
    bus, chip = make_bus(Water())
    chip.set_fault(fault)
    transfers: list[Callable[[], object]] = [
        lambda: bus.read_i2c_block_data(ADDRESS, 0, 2),
        lambda: bus.write_i2c_block_data(ADDRESS, 3, [0x28, 0x00]),
        lambda: bus.read_byte_data(ADDRESS, 1),
        lambda: bus.write_byte_data(ADDRESS, 1, 0),
    ]
    for transfer in transfers:
        with pytest.raises(OSError, match=os.strerror(code)) as caught:
            transfer()
        assert caught.value.errno == code


def test_a_nack_glitch_keeps_the_registers() -> None:
    bus, chip = make_bus(Water())
    bus.write_i2c_block_data(ADDRESS, 0x03, [0x2D, 0x00])  # T_CRIT 90 °C
    bus.write_byte_data(ADDRESS, 0x01, 0x10)
    chip.set_fault("nack")
    chip.set_fault("ok")
    assert word(bus, 0x03) == 0x2D00
    assert bus.read_byte_data(ADDRESS, 0x01) == 0x10


def test_a_chip_plugged_back_in_powers_up_afresh() -> None:
    bus, chip = make_bus(Water())
    bus.write_i2c_block_data(ADDRESS, 0x03, [0x2D, 0x00])  # T_CRIT 90 °C
    bus.write_byte_data(ADDRESS, 0x01, 0x11)  # fault queue, shutdown
    chip.set_fault(Fault.GONE)
    chip.set_fault(Fault.OK)
    assert word(bus, 0x03) == 0x2800  # 80 °C again
    assert bus.read_byte_data(ADDRESS, 0x01) == 0x00


def test_stuck_freezes_the_word_it_had_when_the_fault_began() -> None:
    water = Water(20.0)
    bus, chip = make_bus(water)
    assert word(bus, 0x00) == 0x0A00
    water.celsius = 30.0
    chip.set_fault("stuck")
    water.celsius = 85.0
    assert word(bus, 0x00) == 0x0F00  # 30 °C, no flags: the comparators stopped too
    chip.set_fault("ok")
    assert word(bus, 0x00) == 0x2A86  # 85 °C = 1360 = 0x550 -> 0x2A80, T_CRIT and T_HIGH


def test_stuck_in_shutdown_keeps_the_shutdown_word() -> None:
    water = Water(20.0)
    bus, chip = make_bus(water)
    bus.write_byte_data(ADDRESS, 0x01, 0x01)
    water.celsius = 30.0
    chip.set_fault("stuck")
    assert word(bus, 0x00) == 0x0A00


def test_a_spike_is_one_conversion_then_normal() -> None:
    water = Water(20.0)
    bus, chip = make_bus(water)
    chip.set_fault("spike", -300.0)
    assert word(bus, 0x07) == 0x8001  # other registers do not use it up
    pending = chip.fault
    assert word(bus, 0x00) == 0xE481  # clamped at -55 °C, below T_LOW
    assert (pending, chip.fault) == (Fault.SPIKE, Fault.OK)
    assert word(bus, 0x00) == 0x0A00


def test_wrong_id_changes_only_the_id_register() -> None:
    bus, chip = make_bus(Water(20.0))
    chip.set_fault("wrong_id")
    assert word(bus, 0x07) == 0x0190
    assert word(bus, 0x00) == 0x0A00
    chip.set_fault("wrong_id", 0xA1B2)
    assert bus.read_i2c_block_data(ADDRESS, 0x07, 2) == [0xA1, 0xB2]


def test_slow_transfers_advance_the_injected_clock_and_succeed() -> None:
    clock = VirtualClock(start=100.0)
    chip = FakeLM92(lambda: 20.0 + (clock.monotonic() - 100.0), advance=clock.advance)
    bus = FakeSMBus()
    bus.attach(ADDRESS, chip)
    chip.set_fault("slow", 0.5)
    assert word(bus, 0x00) == 0x0A40  # 20.5 °C = 328 steps = 0x148: read after the delay
    bus.write_byte_data(ADDRESS, 0x01, 0)
    assert clock.monotonic() == 101.0
    chip.set_fault("ok")
    word(bus, 0x00)
    assert clock.monotonic() == 101.0


def test_a_scenario_can_switch_faults_on_the_virtual_clock() -> None:
    clock = VirtualClock()
    bus, chip = make_bus(Water())
    clock.call_at(10.0, lambda: chip.set_fault("nack"))
    clock.call_at(12.0, lambda: chip.set_fault("ok"))
    outcomes = []
    for second in range(9, 14):
        clock.sleep_until(second)
        try:
            word(bus, 0x00)
            outcomes.append("ok")
        except OSError as exc:
            outcomes.append(str(exc.errno))
    assert outcomes == ["ok", "121", "121", "ok", "ok"]


@pytest.mark.parametrize(
    ("kind", "value", "complaint"),
    [
        ("melted", None, "unknown fault 'melted'"),
        ("spike", None, "finite temperature"),
        ("spike", float("nan"), "finite temperature"),
        ("slow", 0.0, "positive number of seconds"),
        ("wrong_id", 0x8001, "other than 0x8001"),
        ("wrong_id", 0x10000, "16-bit"),
        ("wrong_id", 1.5, "16-bit"),
        ("nack", 3.0, "takes no value"),
    ],
)
def test_fault_arguments_are_checked(kind: str, value: float | None, complaint: str) -> None:
    clock = VirtualClock()
    chip = FakeLM92(Water(), advance=clock.advance)
    with pytest.raises(ValueError, match=complaint):
        chip.set_fault(kind, value)
    assert chip.fault is Fault.OK


def test_slow_needs_a_clock_to_advance() -> None:
    chip = FakeLM92(Water())
    with pytest.raises(ValueError, match="advance"):
        chip.set_fault("slow", 0.1)
