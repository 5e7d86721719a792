"""The simulation station: the vehicle, its arm, the panel and the seabed in MuJoCo, paced to
real time, or with simulated time (`time.mode` sim) the system's clock: `time.speed` times real
time, as far as every station keeps up (common.clock). Cameras and sonar render in their own
threads on the simulation's clock."""

from __future__ import annotations

import logging
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from abyss.common import keys
from abyss.common.bus import Bus
from abyss.common.clock import WALL, Holdback, SimClock
from abyss.common.config import Config
from abyss.common.messages import ArmVelocityRef, SimTime, SimulationControl, SimulationStatus, VelocityRef
from abyss.common.workers import Workers

if TYPE_CHECKING:
    from abyss.stations.simulation.world import World

STATUS_PERIOD_S = 1.0
PANEL_EVERY = 2  # control periods: the panel's truth at 10 Hz
log = logging.getLogger(__name__)


def run(config: Config, bus: Bus) -> None:
    sim = config.simulation
    if sim.camera_rate_hz > 0:
        from abyss.stations.simulation.rendering import choose_gl_backend

        choose_gl_backend()  # before MuJoCo is imported
    from abyss.stations.simulation.world import World

    world = World(sim, np.random.default_rng(config.seed))
    if sim.state_file and world.resume(Path(sim.state_file)):
        log.info("resumed at t=%.2f s from %s (a restart)", world.data.time, sim.state_file)
    lock = threading.Lock()
    blackout: set[str] = set()
    with Workers(bus.stop) as workers:
        if sim.camera_rate_hz > 0:
            workers.start("cameras", _camera_loop, config, bus, world, lock, blackout)
        if sim.sonar_rate_hz > 0:
            workers.start("sonar", _sonar_loop, config, bus, world, lock)
        _physics_loop(config, bus, world, lock, blackout)


def _physics_loop(config: Config, bus: Bus, world: World, lock: threading.Lock, blackout: set[str]) -> None:
    """Step the physics at its period, apply the faults asked for, publish the sensors."""
    from abyss.stations.simulation.world import references

    sim = config.simulation
    vehicle = bus.subscribe("onboard", "cmd/vehicle_velocity", maxlen=4)
    arm = bus.subscribe("onboard", "cmd/arm_velocity", maxlen=4)
    control_key = keys.simulation_control_key(bus.system)
    controls = bus.subscribe_key(control_key, "SimulationControl")
    # the wall clock paces the physics, at time.speed (max: as fast as the stations keep up)
    rate = bus.loop("physics", sim.control_period_s / config.time.speed_factor, clock=WALL)
    clock = bus.clock if isinstance(bus.clock, SimClock) else None
    holdback = (Holdback(bus.session, bus.system, config.time.stations, config.time.max_lag_s)
                if clock is not None else None)
    wall0, sim0 = time.monotonic(), world.data.time

    def tell_time(sim_time_s: float) -> None:
        """The simulation's time to its own loops (cameras, sonar) and to every station."""
        assert clock is not None
        clock.tick(sim_time_s)
        bus.observe(keys.clock_key(bus.system), SimTime(sim_time_s=sim_time_s))

    if clock is not None:
        tell_time(world.data.time)  # a resumed simulation starts where it was

    saved_s = -float("inf")  # simulated time of the state last kept
    while True:
        for control in controls.drain():
            assert isinstance(control.message, SimulationControl)
            try:
                with lock:
                    world.apply_fault(control.message, blackout)
            except ValueError as exc:
                bus.reject(control_key, str(exc))
        v, a = vehicle.fresh(sim.command_timeout_s), arm.fresh(sim.command_timeout_s)  # watchdog
        refs = references(v.message if v and isinstance(v.message, VelocityRef) else None,
                          a.message if a and isinstance(a.message, ArmVelocityRef) else None)
        if holdback is not None and clock is not None:
            holdback.hold(world.data.time, bus.stop, clock, lambda: tell_time(world.data.time))
            rate.forgive()  # its deadlines: keeping the speed asked while it is not held back
        with lock:
            world.step(refs, sim.control_period_s)
            truth, joints = world.truth(), world.joints()
            panel = world.panel() if rate.ticks % PANEL_EVERY == 0 else None
        if clock is not None:
            tell_time(truth.sim_time_s)
        bus.publish("nav", world.nav())
        bus.publish("joints", joints)
        bus.observe(keys.truth_key(bus.system), truth)
        if panel is not None:
            bus.observe(keys.panel_truth_key(bus.system), panel)
        if sim.state_file and truth.sim_time_s - saved_s >= sim.state_period_s:
            with lock:
                world.save_state(Path(sim.state_file))
            saved_s = truth.sim_time_s
        wall = time.monotonic()
        if wall - wall0 >= STATUS_PERIOD_S:
            bus.observe(keys.simulation_status_key(bus.system), SimulationStatus(
                sim_time_s=truth.sim_time_s, realtime_factor=(truth.sim_time_s - sim0) / (wall - wall0),
                deadlines_met=rate.deadlines_met, faults=dict(world.faults),
                held_s=holdback.status() if holdback is not None else {}))
            wall0, sim0 = wall, truth.sim_time_s
        if not rate.sleep():
            break
    if holdback is not None:
        holdback.close()


def _camera_loop(config: Config, bus: Bus, world: object, lock: threading.Lock, blackout: set[str]) -> None:
    """Render every camera at the camera rate from a copy of the physics state."""
    import mujoco

    from abyss.common.models import CAMERAS
    from abyss.stations.simulation.encoding import encode_image
    from abyss.stations.simulation.rendering import Cameras

    sim = config.simulation
    model = world.model  # type: ignore[attr-defined]
    snapshot = mujoco.MjData(model)
    cameras = Cameras(model, sim.camera_width_px, sim.camera_height_px, sim.water, sim.marine_snow,
                      np.random.default_rng([config.seed, 1]))  # the optics' own stream: snow, noise
    cameras.blackout = blackout
    rate = bus.loop("cameras", 1.0 / sim.camera_rate_hz)
    try:
        while rate.sleep():
            with lock:
                mujoco.mj_copyData(snapshot, model, world.data)  # type: ignore[attr-defined]
            for camera in CAMERAS:
                bus.publish(f"camera/{camera}", encode_image(cameras, snapshot, camera, sim.jpeg_quality))
    finally:
        cameras.close()


def _sonar_loop(config: Config, bus: Bus, world: World, lock: threading.Lock) -> None:
    """Ping the imaging sonar at its rate from a copy of the physics state."""
    import mujoco

    from abyss.stations.simulation.sonar import ImagingSonar

    sim = config.simulation
    snapshot = mujoco.MjData(world.model)
    sonar = ImagingSonar(world.model)
    rng = np.random.default_rng([config.seed, 2])  # the sonar's own stream: speckle, noise
    rate = bus.loop("sonar", 1.0 / sim.sonar_rate_hz)
    while rate.sleep():
        with lock:
            mujoco.mj_copyData(snapshot, world.model, world.data)
        bus.publish("sonar", sonar.message(snapshot, rng))
