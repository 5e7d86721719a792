"""The twin: the simulation station in a hybrid run (`[hybrid]`), where a real vehicle provides
its navigation and joints (and whatever else `hybrid.vehicle` names) and the twin renders the
sensors it lacks. It runs no dynamics of its own: it places the virtual vehicle at onboard's
navigation estimate as onboard publishes it (`onboard/nav/estimate`: whatever onboard is, this
one, a real one or a ROS 2 node, and from its restart on, so that a frame is rendered where
onboard believes the vehicle is) and the arm at the vehicle's joints, on the virtual site
registered to the vehicle's navigation frame (`hybrid.site_pose`), and renders its sensors from
there at their rates, each frame stamped with the estimate's time it was rendered at. Commands go
to the real vehicle; the twin never moves it. An estimate or joints older than
`hybrid.nav_max_age_s` (by their arrival) stop its sensors, as does none at all, and it says so:
it renders nothing rather than from a pose that is no longer true."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

import mujoco
import numpy as np

from abyss.bus.session import Bus, Inbox
from abyss.common.errors import BadInput
from abyss.common.samples import Samples
from abyss.common.workers import Workers
from abyss.config import Config
from abyss.description.robot import place_at_start, robot_at
from abyss.description.site import site_at, world_model
from abyss.interface import keys
from abyss.interface.messages import JointState, NavState, SimulationControl, SimulationStatus

if TYPE_CHECKING:
    from abyss.stations.simulation.offload import SensorKind

PLACE_PERIOD_S = 0.01  # how often the twin takes what the vehicle sent: the delay it adds, at most
log = logging.getLogger(__name__)


class Twin:
    """The virtual vehicle and arm where the real ones are; a pure core (messages in, the pose
    the sensors render from out: its MuJoCo state, which the sensor loops copy under their lock
    and their processes take forward)."""

    def __init__(self, config: Config) -> None:
        sim, self.hybrid = config.simulation, config.hybrid
        self.robot = robot = robot_at(sim.robot)
        self.model = world_model(robot, site_at(sim.site))
        self.data = mujoco.MjData(self.model)
        place_at_start(self.model, self.data.qpos, robot, sim.start_position_m_world, sim.start_yaw_rad)
        mujoco.mj_forward(self.model, self.data)
        self._base = int(self.model.joint(robot.base).qposadr[0])
        self._arm = np.array([self.model.joint(n).qposadr[0] for n in robot.arm_joints], dtype=int)
        self._fingers = np.array([self.model.joint(n).qposadr[0] for n in robot.gripper_joints], dtype=int)
        self.topics = self.hybrid.twin_topics
        self.nav_arrived_s: float | None = None  # [s, the station's clock] the pose's navigation's arrival
        self.joints_arrived_s: float | None = None
        self.delay_s = Samples()  # from the navigation's arrival to the frame rendered at it
        self.withheld = 0  # sensor turns that rendered nothing: no navigation, or stale

    def take_estimate(self, nav: NavState, arrived_s: float) -> None:
        """Onboard's navigation estimate: the vehicle moves to it."""
        p, q = self.hybrid.site_pose(nav.position_m_world, nav.orientation_wxyz_world)
        self.data.qpos[self._base : self._base + 3] = p
        self.data.qpos[self._base + 3 : self._base + 7] = q / np.linalg.norm(q)
        self.data.time = nav.sim_time_s  # the frames rendered at this pose are stamped with its time
        self.nav_arrived_s = arrived_s

    def take_joints(self, joints: JointState, arrived_s: float) -> None:
        """The arm's joints and the gripper's opening (shared evenly by its fingers)."""
        if len(joints.positions_rad) != len(self._arm):
            raise BadInput(f"{len(joints.positions_rad)} joints, the robot's arm has {len(self._arm)}")
        self.data.qpos[self._arm] = joints.positions_rad
        self.data.qpos[self._fingers] = joints.gripper_opening_m / max(len(self._fingers), 1)
        self.joints_arrived_s = arrived_s

    def why_not(self, now_s: float) -> str:
        """Why the sensors must not render now ("" when they may)."""
        age = self.hybrid.nav_max_age_s
        if self.nav_arrived_s is None:
            return "no navigation estimate from onboard yet"
        if self.joints_arrived_s is None:
            return "no joints from the real vehicle yet"
        if now_s - self.nav_arrived_s > age:
            return f"onboard's navigation estimate is older than hybrid.nav_max_age_s ({age:g} s)"
        if now_s - self.joints_arrived_s > age:
            return f"the joints are older than hybrid.nav_max_age_s ({age:g} s)"
        return ""

    def cameras(self, cameras: tuple[str, ...]) -> tuple[str, ...]:
        """Of the cameras a frame set would render, those whose topics the twin provides."""
        return tuple(c for c in cameras if self.robot.camera_topic(c) in self.topics)

    def renders(self, kind: SensorKind) -> bool:
        if kind == "sonar":
            return "sonar" in self.topics
        return any(self.robot.camera_topic(c) in self.topics for c in self.robot.cameras)

    def status(self) -> dict[str, object]:
        """What the twin did, for summary.json (`about`)."""
        return {
            "twin": {
                "provides": list(self.topics),
                "vehicle_provides": list(self.hybrid.vehicle),
                "withheld": self.withheld,
                "frames": len(self.delay_s),
                **self.delay_s.percentiles("nav_to_frame", 1e3, "ms"),
            }
        }


def run(config: Config, bus: Bus, sensor_loop: Callable[..., None]) -> None:
    """The simulation station as a hybrid run's twin, its sensors rendered by `sensor_loop` (the
    simulation's own, stations.simulation.sensor_loop)."""
    twin = Twin(config)
    lock = threading.Lock()
    blackout: set[str] = set()
    bus.about["physics"] = "twin"
    log.info(
        "twin: the real vehicle provides %s; the twin renders %s, registered at %s m, heading %.3f rad",
        ", ".join(config.hybrid.vehicle),
        ", ".join(twin.topics),
        config.hybrid.site_origin_m_nav,
        config.hybrid.site_heading_rad,
    )
    sim = config.simulation
    sensors: tuple[tuple[SensorKind, float], ...] = (
        ("cameras", sim.camera_rate_hz),
        ("sonar", sim.sonar_rate_hz),
    )
    with Workers(bus.stop) as workers:
        for kind, rate_hz in sensors:
            if rate_hz > 0 and twin.renders(kind):
                workers.start(kind, sensor_loop, config, bus, twin, lock, blackout, kind, rate_hz)
        _place(bus, twin, lock, blackout)
    bus.about.update(twin.status())


def _place(bus: Bus, twin: Twin, lock: threading.Lock, blackout: set[str]) -> None:
    """Take what the real vehicle sends as it comes, and the camera faults; the status each second."""
    nav: Inbox[NavState] = bus.subscribe("onboard", "nav/estimate", NavState)
    joints: Inbox[JointState] = bus.subscribe_key(
        keys.spec("simulation", "joints").key(bus.system), JointState
    )
    control_key = keys.simulation_control_key(bus.system)
    controls = bus.subscribe_key(control_key, SimulationControl)
    rate = bus.loop("placement", PLACE_PERIOD_S)
    said, said_at = "", 0.0  # what the twin last said of its freshness, and when
    status_at = time.monotonic()
    while rate.sleep():
        now_s = bus.clock.now_s()
        with lock:
            for received in nav.drain():
                twin.take_estimate(received.message, now_s)
            for item in joints.drain():
                try:
                    twin.take_joints(item.message, now_s)
                except BadInput as exc:
                    bus.reject(keys.spec("simulation", "joints").key(bus.system), exc.reason)
            why = twin.why_not(now_s)
        for control in controls.drain():
            _fault(bus, control.message, blackout, control_key)
        if why != said:  # once as it begins, once as it ends with how long it lasted
            if why:
                log.warning("twin: %s; its sensors render nothing", why)
            else:
                log.info(
                    "twin: navigation and joints fresh%s; its sensors render at the real vehicle's pose",
                    f" after {now_s - said_at:.1f} s" if said else "",
                )
            said, said_at = why, now_s
        if time.monotonic() - status_at >= 1.0:
            status_at = time.monotonic()
            bus.observe(
                keys.simulation_status_key(bus.system),
                SimulationStatus(float(twin.data.time), 1.0, rate.deadlines_met, {}, {}),
            )


def _fault(bus: Bus, fault: SimulationControl, blackout: set[str], key: str) -> None:
    """The faults a twin can apply: its cameras' (blacked out, back on) and their clearing; the
    others act on dynamics, which are the real vehicle's."""
    if fault.fault == "camera":
        (blackout.add if fault.value == 0.0 else blackout.discard)(fault.target)
    elif fault.fault == "clear":
        blackout.clear()
    else:
        bus.reject(key, f"fault {fault.fault!r}: the twin runs no dynamics; the real vehicle's own are real")
