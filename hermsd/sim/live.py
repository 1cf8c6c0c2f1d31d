"""A scenario run live (`hermsd run --simulate --scenario FILE`): the scenario's tun (a HERMS's
mash tun, coil and pump too), its config and its events, on a clock paced to real time, for a
brewer to watch and command as on a brew day (the status line, `hermsd status` and `set`, the
web page, MQTT). Nothing is measured: `hermsd simulate` measures a scenario."""

from __future__ import annotations

import datetime as dt
import logging
import math
from typing import Any

from hermsd.config.schema import Config
from hermsd.runtime.assemble import assemble
from hermsd.runtime.daemon import Daemon
from hermsd.runtime.saver import Saver
from hermsd.sim.clock import DEFAULT_EPOCH_NS, PacedClock, VirtualClock
from hermsd.sim.scenario import (
    Scenario,
    ScenarioError,
    _Brewer,
    _herms_tun,
    _reloads,
    check_events,
    schedule_events,
)
from hermsd.sim.world import build_world

log = logging.getLogger("hermsd")


def scenario_daemon(scenario: Scenario, config: Config, speed: float, **parts: Any) -> Daemon:
    """The daemon on `scenario`'s tun, `speed` times real time (inf: as fast as it goes), its
    events at their times and its program started half a period in; `config` is the
    scenario's effective one (`scenario.effective_config`), `parts` go to `assemble`.
    ScenarioError for a scenario the simulated hardware cannot run."""
    clock = _clock(scenario, speed)
    try:
        tun = _herms_tun(config, scenario.plant) if "mash" in scenario.plant else None
        world = build_world(config, clock, scenario.plant, tun=tun)
    except (TypeError, ValueError) as error:
        raise ScenarioError(f"plant: {error}") from None
    check_events(scenario, config, world)
    mash = world.mash
    daemon = assemble(
        config,
        clock,
        world.sensor,
        world.outputs,
        mash_sensor=None if mash is None else mash.mash_sensor,
        coil_sensor=None if mash is None else mash.coil_sensor,
        pump_sense=None if mash is None else mash.pump_sense,
        current_sense=world.current,
        saver=Saver(threaded=not math.isinf(speed)),
        **parts,
    )
    brewer = _Brewer(daemon)
    daemon.listeners.append(brewer)
    schedule_events(scenario, _reloads(config, scenario), clock, world, daemon, brewer)
    program = scenario.program
    if program is not None:

        def start_program() -> None:  # as a brewer would, with the daemon running
            problems = daemon.program_problems(program)  # one resumed from the state runs
            if problems:
                log.warning("program %r not started: %s", program.name, "; ".join(problems))
            else:
                daemon.start_program(program, None, clock.monotonic())

        clock.call_at(config.control.period / 2, start_program)
    return daemon


def _clock(scenario: Scenario, speed: float) -> VirtualClock:
    """The run's clock, on the scenario's wall clock and local zone (`clock:`) if it has one."""
    epoch, zone = scenario.clock or (DEFAULT_EPOCH_NS, dt.UTC)
    if math.isinf(speed):
        return VirtualClock(0.0, epoch, zone)
    paced = PacedClock(speed, epoch)
    paced.zone = zone
    return paced
