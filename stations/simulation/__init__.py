"""The simulation station: the vehicle, its arm, the panel and the seabed in MuJoCo, paced to
real time, or with simulated time (`time.mode` sim) the system's clock: `time.speed` times real
time, as far as every station keeps up (timing.clock). Cameras and sonar render in their own
threads on the simulation's clock."""

from __future__ import annotations

import itertools
import logging
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from abyss.bus.session import Bus
from abyss.common.errors import BadInput
from abyss.common.workers import Realtime, Workers
from abyss.config import Config, robot_of
from abyss.description.models import stereo_set
from abyss.interface import keys
from abyss.interface.messages import (
    ArmVelocityRef,
    JointState,
    NavState,
    PanelState,
    SimTime,
    SimulationControl,
    SimulationStatus,
    VelocityRef,
)
from abyss.timing.clock import WALL, Holdback, SimClock
from abyss.timing.lockstep import TICK_TOLERANCE_S, Lockstep

if TYPE_CHECKING:
    from abyss.stations.simulation.json_backend import JsonBackend
    from abyss.stations.simulation.offload import SensorKind
    from abyss.stations.simulation.twin import Twin
    from abyss.stations.simulation.world import World

STATUS_PERIOD_S = 1.0
PANEL_EVERY = 2  # control periods: the panel's truth at 10 Hz
log = logging.getLogger(__name__)


def loops(config: Config) -> tuple[str, ...]:
    """The station's named loops besides the physics (lockstep runs no period before they are all
    there; the physics is lockstep's master)."""
    sim = config.simulation
    return (*(("cameras",) if sim.camera_rate_hz > 0 else ()), *(("sonar",) if sim.sonar_rate_hz > 0 else ()))


def run(config: Config, bus: Bus) -> None:
    """The station: the whole simulation, or in a hybrid run (`hybrid.vehicle`) the twin of a
    real vehicle (twin.py)."""
    sim = config.simulation
    if sim.camera_rate_hz > 0:
        from abyss.stations.simulation.rendering import choose_gl_backend

        choose_gl_backend()  # before MuJoCo is imported
    if config.hybrid.on:
        from abyss.stations.simulation import twin

        twin.run(config, bus, sensor_loop)
        return
    from abyss.stations.simulation.world import World

    world = World(sim, np.random.default_rng(config.seed))
    bus.about["physics"] = world.runs_in
    if sim.state_file and world.resume(Path(sim.state_file)):
        log.info("resumed at t=%.2f s from %s (a restart)", world.data.time, sim.state_file)
    backend = _autopilot_backend(config, world)
    lock = backend.lock if backend is not None else threading.Lock()
    blackout: set[str] = set()
    bus.realtime = Realtime(sim.realtime_priority, why_not=_no_realtime(config))
    with Workers(bus.stop) as workers:
        sensors: tuple[tuple[SensorKind, float], ...] = (
            ("cameras", sim.camera_rate_hz),
            ("sonar", sim.sonar_rate_hz),
        )
        for kind, rate_hz in sensors:
            if rate_hz > 0:
                workers.start(kind, sensor_loop, config, bus, world, lock, blackout, kind, rate_hz)
        if backend is None:
            _physics_loop(config, bus, world, lock, blackout)
            return
        from abyss.stations.simulation.json_backend import bind, serve

        sock = bind("127.0.0.1", config.mavlink.json_port, "mavlink.json_port")
        workers.start("ardupilot", serve, backend, sock, bus.stop)
        _autopilot_loop(config, bus, world, backend)


def _autopilot_backend(config: Config, world: World) -> JsonBackend | None:
    """With ArduSub as the autopilot (mavlink.autopilot), the JSON physics its frames step."""
    if not config.mavlink.autopilot:
        return None
    from abyss.stations.simulation.json_backend import JsonBackend

    backend = JsonBackend(world)
    log.info("ArduSub flies the vehicle: its JSON physics on udp 127.0.0.1:%d", config.mavlink.json_port)
    return backend


def _autopilot_loop(config: Config, bus: Bus, world: World, backend: JsonBackend) -> None:
    """ArduSub's frames step the physics (json_backend); this loop hands it onboard's arm and
    gripper velocities and publishes the sensors, the truth and the status at the control period."""
    from abyss.stations.simulation.world import references

    sim = config.simulation
    bus.subscribe("onboard", "cmd/vehicle_velocity", VelocityRef, maxlen=1)  # ArduSub's to fly
    bus.subscribe("onboard", "nav/estimate", NavState, maxlen=1)
    arm = bus.subscribe("onboard", "cmd/arm_velocity", ArmVelocityRef, maxlen=4)
    keeper = Timekeeper(config, bus, world.data.time)
    status_since = time.monotonic(), world.data.time
    for step in itertools.count():
        fresh = arm.fresh(sim.command_timeout_s)
        backend.arm = references(None, fresh.message if fresh else None)
        with backend.lock:  # ArduSub's frames step the world in the backend's thread
            nav, truth, joints = world.nav(), world.truth(), world.joints()
            panel = world.panel() if step % PANEL_EVERY == 0 else None
        _publish(bus, nav, truth, joints, panel)
        status_since = _report_status(bus, world, keeper, truth.sim_time_s, status_since)
        if not keeper.rate.sleep():
            break
    keeper.close()


def _no_realtime(config: Config) -> str:
    """Why the physics must not run at real-time priority here, if it must not."""
    if config.time.mode != "real":
        return f"time.mode {config.time.mode}: the stations' progress paces the physics, not deadlines"
    if config.cpu.simulation:
        return f"cpu.simulation {config.cpu.simulation} core: the real-time scheduler would pass the cap by"
    return ""


def _physics_loop(config: Config, bus: Bus, world: World, lock: threading.Lock, blackout: set[str]) -> None:
    """Step the physics at its period, apply the faults asked for, publish the sensors."""
    from abyss.stations.simulation.faults import apply as apply_fault
    from abyss.stations.simulation.world import references

    sim = config.simulation
    vehicle = bus.subscribe("onboard", "cmd/vehicle_velocity", VelocityRef, maxlen=4)
    arm = bus.subscribe("onboard", "cmd/arm_velocity", ArmVelocityRef, maxlen=4)
    # onboard's estimate, which a twin renders at (twin.py): the whole simulation has the truth, and
    # takes it (validated, counted, recorded as every key's receiver does) only to let it go
    bus.subscribe("onboard", "nav/estimate", NavState, maxlen=1)
    control_key = keys.simulation_control_key(bus.system)
    controls = bus.subscribe_key(control_key, SimulationControl)
    keeper = Timekeeper(config, bus, world.data.time)
    rate = keeper.rate
    status_since = time.monotonic(), world.data.time  # wall [s], simulated [s] of the last status
    saved_s = -float("inf")  # simulated time of the state last kept

    def apply_controls() -> int:
        """The faults asked for since the last call, applied; how many."""
        applied = 0
        for control in controls.drain():
            try:
                with lock:
                    apply_fault(world, control.message, blackout)
                applied += 1
            except BadInput as exc:
                bus.reject(control_key, exc.reason)
        return applied

    def keep_state() -> None:
        if sim.state_file:
            with lock:
                world.save_state(Path(sim.state_file))

    for step in itertools.count():
        if not keeper.before_step(world.data.time, keep_state, apply_controls):
            break
        apply_controls()
        v, a = vehicle.fresh(sim.command_timeout_s), arm.fresh(sim.command_timeout_s)  # watchdog
        refs = references(v.message if v else None, a.message if a else None)
        stepped_from_s = world.data.time
        keeper.inputs_taken(stepped_from_s)
        with lock:
            world.step(refs, sim.control_period_s)
            truth, joints = world.truth(), world.joints()
            panel = world.panel() if step % PANEL_EVERY == 0 else None
        _publish(bus, world.nav(), truth, joints, panel)
        if sim.state_file and truth.sim_time_s - saved_s >= sim.state_period_s:
            with lock:
                world.save_state(Path(sim.state_file))
            saved_s = truth.sim_time_s
        status_since = _report_status(bus, world, keeper, truth.sim_time_s, status_since)
        if not keeper.after_step(stepped_from_s, truth.sim_time_s):
            break
        bus.realtime.tick(rate.late)
    keeper.close()


def _publish(bus: Bus, nav: NavState, truth: NavState, joints: JointState, panel: PanelState | None) -> None:
    """A control period's outputs: the navigation sensors' readings and the joints to onboard,
    the truth (and the panel's, when due) to the testbed."""
    bus.publish("nav", nav)
    bus.publish("joints", joints)
    if panel is not None:  # before the truth: the supervisor that has the truth has the panel's
        bus.observe(keys.panel_truth_key(bus.system), panel)
    bus.observe(keys.truth_key(bus.system), truth)


def _report_status(
    bus: Bus, world: World, keeper: Timekeeper, sim_time_s: float, since: tuple[float, float]
) -> tuple[float, float]:
    """The station's status to the testbed once STATUS_PERIOD_S of the wall clock has passed
    `since` (the wall [s] and simulated [s] times of the last); the new `since`."""
    wall0, sim0 = since
    wall = time.monotonic()
    if wall - wall0 < STATUS_PERIOD_S:
        return since
    bus.observe(
        keys.simulation_status_key(bus.system),
        SimulationStatus(
            sim_time_s=sim_time_s,
            realtime_factor=(sim_time_s - sim0) / (wall - wall0),
            deadlines_met=keeper.rate.deadlines_met,
            faults=dict(world.faults),
            held_s=keeper.held_s(),
        ),
    )
    return wall, sim_time_s


class Timekeeper:
    """How the physics loop keeps time. Real time: its rate, on the wall clock. Simulated time: the
    wall clock paces it at time.speed (max: not at all), it tells every station its time after
    each step, and waits before a step for the slowest station (Holdback). Lockstep: each period
    is run by timing.lockstep (links, neighbours, the cameras' and sonar's turns) before the step,
    and every station is done with it before the next; at time.end_s it stops advancing."""

    def __init__(self, config: Config, bus: Bus, start_s: float) -> None:
        self.bus, self.time = bus, config.time
        period_s = config.simulation.control_period_s
        self.lockstep: Lockstep | None = bus.lockstep
        self.rate = bus.loop("physics", 0.0 if self.lockstep else period_s / self.time.speed_factor, WALL)
        self.clock = bus.clock if isinstance(bus.clock, SimClock) and self.lockstep is None else None
        self.holdback = (
            Holdback(bus.session, bus.system, self.time.stations, self.time.max_lag_s, bus.reject)
            if self.clock is not None
            else None
        )
        if self.holdback is not None and self.clock is not None:
            holdback = self.holdback
            self.clock.on_progress = lambda _t_s: holdback.notify()  # its own cameras' and sonar's
        self.waited_wall_s = 0.0  # lockstep: for the stations to finish their periods
        if self.time.simulated and self.lockstep is None:
            self.tell(start_s)  # a resumed simulation starts where it was (lockstep: at its period)

    def tell(self, sim_time_s: float) -> None:
        """The simulation's time to its own loops (cameras, sonar) and to every station."""
        if self.clock is not None:
            self.clock.tick(sim_time_s)
        self.bus.observe(keys.clock_key(self.bus.system), SimTime(sim_time_s=sim_time_s))

    def before_step(self, t_s: float, keep_state: Callable[[], None], apply: Callable[[], int]) -> bool:
        """Wait until the physics may step from `t_s`; False once the station stops. Lockstep:
        at a hold, the state kept first (a restart resumes on the hold's period), then held until
        the testbed releases it, applying the faults it sends meanwhile (`apply`)."""
        if self.lockstep is not None:
            while self.time.end_s and t_s >= self.time.end_s - TICK_TOLERANCE_S:
                if self.bus.stop.wait(0.5):  # the run's end: it holds still, telling its time
                    return False
                self.tell(t_s)
            if self.lockstep.hold_at(t_s):
                keep_state()
                if not self.lockstep.hold(t_s, apply):
                    return False
            self.tell(t_s)
            return self.lockstep.period(t_s, lambda: self.tell(t_s))
        if self.holdback is not None and self.clock is not None:
            self.holdback.hold(t_s, self.bus.stop, self.clock, lambda: self.tell(t_s))
            self.rate.forgive()  # its deadlines: keeping the speed asked while it is not held back
        return not self.bus.stop.is_set()

    def inputs_taken(self, t_s: float) -> None:
        """Lockstep: the physics has read its inputs for the period `t_s`, so onboard may deliver
        the next period's while it steps (Lockstep.deliver_ahead)."""
        if self.lockstep is not None:
            self.lockstep.report(t_s, "done")

    def after_step(self, from_s: float, to_s: float) -> bool:
        """The step from `from_s` to `to_s` is done: tell, or wait until every station is done with
        the period; False once the station stops."""
        if self.lockstep is not None:
            lockstep, wall0 = self.lockstep, time.monotonic()
            done = lockstep.wait_for(
                f"every station done at t={from_s:.2f} s",
                lambda: all(
                    lockstep.reported(station, "done")[0] >= from_s - TICK_TOLERANCE_S
                    for station in self.time.stations
                ),
                lambda: self.tell(from_s),
            )
            self.waited_wall_s += time.monotonic() - wall0
            return done
        if self.clock is not None:
            self.tell(to_s)
        return self.rate.sleep()

    def held_s(self) -> dict[str, float]:
        """Wall seconds the simulation waited on each station (lockstep: on them all)."""
        if self.holdback is not None:
            return self.holdback.status()
        return {"stations": round(self.waited_wall_s, 3)} if self.lockstep is not None else {}

    def close(self) -> None:
        if self.holdback is not None:
            self.holdback.close()


def sensor_loop(
    config: Config,
    bus: Bus,
    world: World | Twin,
    lock: threading.Lock,
    blackout: set[str],
    kind: SensorKind,
    rate_hz: float,
) -> None:
    """Render a sensor (`kind`: the cameras, the sonar) at its rate from a copy of the physics
    state, in a process of its own (stations.simulation.offload); on simulated time its messages
    go out `simulation.sensor_latency_s` after the state was taken. A hybrid run's twin renders
    only what it provides, and nothing while its navigation is missing or stale."""
    from abyss.stations.simulation.offload import Offloaded, state_of
    from abyss.stations.simulation.twin import Twin

    twin = world if isinstance(world, Twin) else None

    stream = {"cameras": 1, "sonar": 2}[kind]  # the sensor's own random stream: snow, speckle, noise
    sensor = Offloaded(kind, world.model, config.simulation, [config.seed, stream])
    rate = bus.loop(kind, 1.0 / rate_hz)
    try:
        while rate.sleep():
            with lock:
                if twin is not None and twin.why_not(bus.clock.now_s()):
                    twin.withheld += 1
                    continue
                state = state_of(world.data)
                placed_s = twin.nav_arrived_s if twin is not None else None
            taken_s = bus.clock.now_s()
            cameras = cameras_of_set(config, state["time"])
            sensor.submit(
                state, blackout, twin.cameras(cameras) if twin is not None else cameras, world.robot
            )
            # on simulated time the frames leave the sensor its latency after they were taken,
            # the physics and the stations going on meanwhile (Clock.after_work)
            if not bus.clock.after_work(taken_s, config.simulation.sensor_latency_s, bus.stop):
                break
            for topic, message in sensor.collect():
                bus.publish(topic, message)
            if twin is not None and placed_s is not None:
                twin.delay_s.add(bus.clock.now_s() - placed_s)
    finally:
        sensor.close()


def cameras_of_set(config: Config, sim_time_s: float) -> tuple[str, ...]:
    """The cameras rendered for the frame set taken at `sim_time_s` [s]: each at the rate it is
    consumed, the stereo pair's right camera only on the sets onboard's stereo matcher uses
    (description.models.stereo_set), and not at all without the stereo source."""
    onboard, robot = config.onboard, robot_of(config)
    right = "stereo" in onboard.cloud_sources and stereo_set(
        sim_time_s, config.simulation.camera_rate_hz, onboard.stereo_every
    )
    return tuple(camera for camera in robot.cameras if camera != robot.stereo_right or right)
