"""The commissioning experiments on the simulated tun: `hermsd tune step --simulate`.

Here, above the simulator, so that the simulator needs nothing of commissioning."""

from __future__ import annotations

from typing import Any

from hermsd.commissioning.step_response import StepExperiment
from hermsd.config.file import at_once
from hermsd.config.schema import Config
from hermsd.runtime.assemble import assemble
from hermsd.sim.clock import VirtualClock
from hermsd.sim.world import World, build_world


def simulated_step_test(
    config: Config,
    plant: dict[str, Any],
    output: float | None = None,
    limit: float | None = None,
    *,
    history: bool = False,
) -> tuple[StepExperiment, World, VirtualClock]:
    """`hermsd tune step` on the simulated tun `plant`, ready to run (step_response.run), on a
    virtual clock: output None is the default step, limit None the setpoint."""
    clock = VirtualClock()
    world = build_world(config, clock, plant, history=history)
    daemon = assemble(config, clock, world.sensor, world.outputs)
    stop_at = config.control.setpoint if limit is None else limit
    return StepExperiment(daemon, output, stop_at, fits=at_once), world, clock
