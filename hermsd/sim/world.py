"""The simulated hardware wired together: tun model, fake sensor (sim/sensors.py), heater circuit;
around a HERMS (`sim/mash.py`) the mash's and the coil outlet's fake sensors and the pump.

One place builds it, for `hermsd run --simulate`, `hermsd sensor --simulate` and the
scenario runner alike.
"""

from __future__ import annotations

import errno
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol, cast

from hermsd.config.file import ConfigFile
from hermsd.config.schema import ROLE_SENSORS, Config
from hermsd.control.learning import ModelStore
from hermsd.hardware.lm92 import LM92
from hermsd.hardware.outputs import Outputs, guard_outputs
from hermsd.hardware.sensors.base import Sensor
from hermsd.runtime.assemble import assemble
from hermsd.runtime.clock import Clock
from hermsd.runtime.daemon import Daemon
from hermsd.runtime.notify import Notifier
from hermsd.runtime.saver import Saver
from hermsd.safety.latches import LatchStore
from hermsd.sim.bus import FakeLM92, FakeSMBus
from hermsd.sim.circuit import CircuitCurrent, HeaterCircuit
from hermsd.sim.clock import PacedClock, VirtualClock
from hermsd.sim.hlt import Plant, TwoElementPlant, make_plant
from hermsd.sim.mash import HermsPlant
from hermsd.sim.sensors import FakeChip, fake_sensor, sensor_reading


@dataclass(slots=True)
class World:
    clock: Clock
    plant: Plant
    chip: FakeChip
    sensor: Sensor
    circuit: HeaterCircuit
    outputs: Outputs
    mash: MashSide | None = None  # around a HERMS plant
    current: CircuitCurrent | None = None  # the element's current input (`current.kind`)


@dataclass(slots=True)
class MashSide:
    """The mash's fake sensor and the coil outlet's, as fitted (their chips switch into
    faults as the HLT's does), for `assemble`'s `mash_sensor` and `coil_sensor`."""

    mash_sensor: Sensor | None = None
    mash_chip: FakeChip | None = None
    coil_sensor: Sensor | None = None
    coil_chip: FakeChip | None = None
    pump_sense: PumpContact | None = None


class PumpSwitch:
    """The simulated pump's switch: runs or stops the plant's pump on the clock's time."""

    def __init__(self, plant: HermsPlant, clock: Clock) -> None:
        self._plant = plant
        self._clock = clock

    def set(self, on: bool) -> None:
        self._plant.set_pump(on, self._clock.monotonic())

    def close(self) -> None:
        """Nothing to release."""


class SensedPlant(Protocol):
    """A HERMS plant that says whether its pump runs (`HermsTun`; one from outside may not)."""

    def pump_running(self) -> bool: ...


class PumpContact:
    """The simulated pump sense (`pump.sense`, in a simulated world): the plant's pump as a
    contact on its supply says it, by whatever set it (a scenario's `pump` event); `failing`
    makes each read an OSError, as a GPIO line that cannot be read."""

    def __init__(self, plant: SensedPlant) -> None:
        self._plant = plant
        self.failing = False

    def running(self) -> bool:
        if self.failing:
            raise OSError(errno.EIO, "the pump sense's line cannot be read (simulated)")
        return self._plant.pump_running()

    def close(self) -> None:
        """Nothing to release."""


def _mash_side(
    config: Config, clock: Clock, tun: Plant, advance: Callable[[float], None] | None
) -> tuple[MashSide | None, PumpSwitch | None]:
    """Around a HERMS plant, the fake sensors the config fits beside the HLT's, and the pump;
    a config that fits them around a plant without a mash is refused."""
    fitted = [s for s in ROLE_SENSORS if getattr(config, s).fitted]
    if config.pump.backend != "none":
        fitted.append("pump")
    if config.pump.sense != "none":
        fitted.append("pump sense")
    if not isinstance(tun, HermsPlant):
        if fitted:
            raise ValueError(
                f"{' and '.join(fitted)} configured, but the simulated plant has no mash tun"
            )
        return None, None
    mash, coil = config.mash_sensor, config.coil_sensor
    side = MashSide()

    def now(temperature: Callable[[float], float]) -> Callable[[], float]:
        return lambda: temperature(clock.monotonic())

    if mash.fitted:
        source = now(tun.mash_temperature)
        side.mash_sensor, side.mash_chip = fake_sensor(mash, clock.monotonic, source, advance)
    if coil.fitted:
        source = now(tun.coil_outlet_temperature)
        side.coil_sensor, side.coil_chip = fake_sensor(coil, clock.monotonic, source, advance)
    pump = PumpSwitch(tun, clock) if config.pump.backend != "none" else None
    if config.pump.sense != "none":  # the simulated contact, whatever the config names
        if not callable(getattr(tun, "pump_running", None)):
            raise ValueError("pump.sense: the simulated plant cannot say whether its pump runs")
        side.pump_sense = PumpContact(cast(SensedPlant, tun))
    return side, pump


SENSOR_KEYS = ("noise_c", "seed")
"""Keys of a `plant:` mapping that describe the sensor, not the tun."""


def build_world(
    config: Config,
    clock: Clock,
    plant: dict[str, Any] | None = None,
    *,
    tun: Plant | None = None,
    history: bool = False,
) -> World:
    """Simulated hardware for `config`, on `clock`, around a plant (`{"model": ..., **params}`)
    or around `tun`, a plant built elsewhere (then only the mapping's sensor keys count).

    `history`: the circuit keeps every edge and power change (a scenario's measurements).
    """
    spec = dict(plant or {"model": "foptd"})
    noise_c = spec.pop("noise_c", 0.0)
    seed = spec.pop("seed", 0)
    model = spec.pop("model", "foptd")
    if tun is None:
        if config.element2.backend != "none":
            spec.setdefault("element2_watts", config.element2.watts)
        tun = make_plant(model, **spec)
    advance = clock.advance if isinstance(clock, VirtualClock) else None
    source = sensor_reading(tun, clock, noise_c, seed)
    sensor, chip = fake_sensor(config.sensor, clock.monotonic, source, advance)
    contactor = config.contactor.backend != "none"
    two = None
    if config.element2.backend != "none":
        if not isinstance(tun, TwoElementPlant):
            raise ValueError("element2 is configured, but the plant has no second element")
        two = tun
    circuit = HeaterCircuit(tun, clock.monotonic, contactor, history=history, element2=two)
    mash, pump = _mash_side(config, clock, tun, advance)
    outputs = guard_outputs(circuit.ssr, circuit.contactor, clock, config, circuit.relay2, pump)
    current = None
    if config.current.fitted:  # the simulated circuit's, whatever kind the config names
        current = CircuitCurrent(circuit, config.tun.element_watts, config.current.threshold)
    return World(clock, tun, chip, sensor, circuit, outputs, mash, current)


def simulated_daemon(
    config: Config,
    speed: float,
    on_status: Callable[[str], None] | None = None,
    notifier: Notifier | None = None,
    config_file: ConfigFile | None = None,
    latches: LatchStore | None = None,
    models: ModelStore | None = None,
) -> Daemon:
    """The daemon on the simulated tun, `speed` times real time (inf: as fast as possible)."""
    clock: Clock = VirtualClock() if math.isinf(speed) else PacedClock(speed)
    world = build_world(config, clock)
    mash = world.mash or MashSide()
    return assemble(
        config,
        clock,
        world.sensor,
        world.outputs,
        mash_sensor=mash.mash_sensor,
        coil_sensor=mash.coil_sensor,
        pump_sense=mash.pump_sense,
        current_sense=world.current,
        notifier=notifier,
        on_status=on_status,
        config_file=config_file,
        latches=latches,
        models=models,
        saver=Saver(threaded=not math.isinf(speed)),  # a virtual day's disk takes no time
    )


def simulated_sensor(address: int) -> tuple[LM92, Callable[[float], None]]:
    """An LM92 on the fake bus in a tun of cold water with a little sensor noise."""
    clock = VirtualClock()
    tun = make_plant("physical", start_c=17.3)
    chip = FakeLM92(sensor_reading(tun, clock, noise_c=0.04, seed=1))
    bus = FakeSMBus()
    bus.attach(address, chip)
    return LM92(bus, address, bus_name="sim"), clock.sleep
