"""The simulation station: the vehicle in MuJoCo, paced to real time."""

from __future__ import annotations

import time

from common.bus import Bus
from common.config import Config
from common.messages import VelocityRef
from common.rate import Rate
from stations.simulation.world import World


def run(config: Config, bus: Bus) -> None:
    sim = config.simulation
    world = World(sim)
    commands = bus.subscribe("onboard", "cmd/vehicle_velocity")
    rate = Rate(sim.control_period_s / sim.realtime_factor, bus.stop)
    while True:
        latest = commands.latest()
        fresh = latest is not None and time.time() - latest.stamp_s < sim.command_timeout_s
        command = latest.message if fresh and latest else None
        world.step(command if isinstance(command, VelocityRef) else None, sim.control_period_s)
        bus.publish("nav", world.nav_state())
        if not rate.sleep():
            return
