"""MAX31865 with a PT100/PT1000: hand-computed Callendar–Van Dusen, the datasheet's codes,
and every fault status bit as a sensor fault, through a fake spidev byte for byte."""

from __future__ import annotations

import pytest

from hermsd.hardware.lm92 import SensorError
from hermsd.hardware.sensors.max31865 import (
    MAX31865,
    RtdFault,
    celsius_of,
    code_of,
    decode,
    resistance,
)
from hermsd.sim.spi import FakeMAX31865, FakeSpiDev

# IEC 60751 by hand, R0 = 100 Ω:
#  100 °C: 1 + 0.39083 − 0.005775 = 1.385055 → 138.5055 Ω
#   66 °C: 1 + 0.2579478 − 0.00251559 = 1.25543221 → 125.543221 Ω
# −100 °C: 1 − 0.39083 − 0.005775 + (−4.183e-12)(−200)(−1e6) = 0.6025584 → 60.25584 Ω
# −200 °C: 1 − 0.78166 − 0.0231 + (−4.183e-12)(−300)(−8e6) = 1 − 0.78166 − 0.0231 − 0.0100392
#          = 0.1852008 → 18.52008 Ω (the standard's table: 18.52 Ω)
HAND = [(100.0, 138.5055), (66.0, 125.543221), (-100.0, 60.25584), (-200.0, 18.52008)]


@pytest.mark.parametrize(("celsius", "ohms"), HAND)
def test_callendar_van_dusen_both_ways(celsius: float, ohms: float) -> None:
    assert resistance(celsius, 100.0) == pytest.approx(ohms, abs=1e-9)
    assert resistance(celsius, 1000.0) == pytest.approx(10 * ohms, abs=1e-8)
    assert celsius_of(ohms, 100.0) == pytest.approx(celsius, abs=1e-9)


# The datasheet's table of ADC codes for a PT100 with a 400 Ω reference: code = R/400 × 2^15
@pytest.mark.parametrize(
    ("celsius", "code"), [(-200, 1517), (-100, 4936), (0, 8192), (100, 11346), (200, 14406)]
)
def test_datasheet_codes(celsius: float, code: int) -> None:
    assert code_of(resistance(celsius, 100.0), 400.0) == code
    # one code is 400/32768 = 0.0122 Ω, at most 0.029 °C at −200 °C (0.43 Ω/°C)
    assert decode(code << 1, 0, 100.0, 400.0) == pytest.approx(celsius, abs=0.03)


def test_an_rtd_register_with_the_usual_430_ohm_reference() -> None:
    # 0 °C: 100/430 × 32768 = 7620.47 → code 7620, register 7620 × 2 = 0x3b88;
    # back: 7620/32768 × 430 = 99.99389 Ω, 0.00611 Ω below R0 at 0.39083 Ω/°C = −0.0156 °C
    assert code_of(100.0, 430.0) == 7620
    assert decode(0x3B88, 0, 100.0, 430.0) == pytest.approx(-0.0156, abs=2e-4)


@pytest.mark.parametrize(
    ("status", "words"),
    [
        (0x80, "above the high threshold"),
        (0x40, "below the low threshold"),
        (0x20, "reference resistor is open"),
        (0x10, "FORCE- is open"),
        (0x08, "RTDIN- is open"),
        (0x04, "over- or under-voltage"),
    ],
)
def test_each_fault_bit_is_a_fault(status: int, words: str) -> None:
    with pytest.raises(RtdFault, match=words) as caught:
        decode(0x3B89, status, 100.0, 430.0)
    assert caught.value.status == status


def test_a_fault_bit_without_status_and_a_zero_code_are_faults() -> None:
    with pytest.raises(RtdFault, match="read it again"):
        decode(0x3B89, 0, 100.0, 430.0)
    with pytest.raises(RtdFault, match="code 0"):
        decode(0x0000, 0, 100.0, 430.0)


def rig(
    celsius: float = 66.0, wires: int = 3, filter_hz: int = 50, r0: float = 100.0
) -> tuple[MAX31865, FakeMAX31865, list[float]]:
    source = [celsius]
    chip = FakeMAX31865(lambda: source[0], r0=r0, rref=4.3 * r0)
    spi = FakeSpiDev({(0, 0): chip})
    spi.open(0, 0)
    spi.mode = 1
    driver = MAX31865(spi, r0=r0, rref=4.3 * r0, wires=wires, filter_hz=filter_hz)
    return driver, chip, source


@pytest.mark.parametrize(
    ("wires", "filter_hz", "config"),
    [(2, 50, 0xC1), (3, 50, 0xD1), (4, 60, 0xC0), (3, 60, 0xD0)],
)
def test_the_configuration_byte(wires: int, filter_hz: int, config: int) -> None:
    driver, chip, _ = rig(wires=wires, filter_hz=filter_hz)
    driver.identify()
    assert chip.registers[0] == config  # bias, auto, 3-wire bit, 50 Hz bit


@pytest.mark.parametrize("r0", [100.0, 1000.0])
def test_a_read_through_the_fake(r0: float) -> None:
    driver, _, _ = rig(66.0, r0=r0)
    driver.identify()
    reading = driver.read()
    # 125.543221 Ω / 430 Ω × 32768 = 9566.98 → 9566; back: 125.53082 Ω → 65.9677 °C
    # (the slope at 66 °C is 100 × (A + 2 × B × 66) = 0.383207 Ω/°C)
    assert reading.raw == 9566
    assert reading.celsius == pytest.approx(
        66.0 - (125.543221 - 9566 / 32768 * 430) / 0.383207, abs=1e-4
    )


@pytest.mark.parametrize(
    ("fault", "bits"),
    [
        ("open", 0x80 | 0x10),
        ("short", 0x40),
        ("refin", 0x10),
        ("rtdin", 0x08),
        ("voltage", 0x04),
    ],
)
def test_each_fake_fault_is_read_cleared_and_raised(fault: str, bits: int) -> None:
    driver, chip, _ = rig()
    driver.identify()
    chip.set_fault(fault)
    with pytest.raises(RtdFault) as caught:
        driver.read()
    assert caught.value.status == bits
    assert chip.registers[7] == 0  # cleared on the chip
    chip.set_fault("ok")
    assert driver.read().celsius == pytest.approx(66.0, abs=0.04)


def test_an_absent_chip_is_refused_at_identify() -> None:
    driver, chip, _ = rig()
    chip.set_fault("gone")
    with pytest.raises(SensorError, match="no MAX31865 answers"):
        driver.identify()


def test_the_fake_refuses_a_wrong_spi_mode() -> None:
    spi = FakeSpiDev({(0, 0): FakeMAX31865(lambda: 20.0)})
    spi.open(0, 0)
    with pytest.raises(ValueError, match="mode 1 or 3"):
        spi.xfer2([0x00, 0x00])


def test_bad_settings_are_refused() -> None:
    spi = FakeSpiDev({})
    with pytest.raises(ValueError, match="2, 3 or 4"):
        MAX31865(spi, wires=5)
    with pytest.raises(ValueError, match="50 or 60"):
        MAX31865(spi, filter_hz=55)
    with pytest.raises(ValueError, match="must exceed R0"):
        MAX31865(spi, r0=1000.0, rref=430.0)
