"""The system's sections of the configuration: the links (`[links]`), the mission (`[mission]`),
the recording (`[record]`), CPU caps (`[cpu]`), the time source (`[time]`) and the ROS 2 gateway
(`[ros2]`)."""

from __future__ import annotations

import dataclasses
import math
import re
import typing
from dataclasses import dataclass
from typing import Literal

import numpy as np

from abyss.common.errors import BadInput, ConfigError
from abyss.common.geometry import quat_wxyz_of, rotation_of_rpy
from abyss.config.fields import one_of, positive
from abyss.config.linkprofile import LinkProfile, load_profiles, profile
from abyss.description.models.panel import intent_of
from abyss.interface import keys


@dataclass(frozen=True)
class LinksConfig:
    """Profile name per hop, from config/profiles.toml."""

    rov: str = "ideal"
    tether: str = "tether"
    satellite: str = "satellite"

    def __post_init__(self) -> None:
        available = load_profiles()
        for hop in keys.HOPS:
            name = getattr(self, hop)
            if name not in available:
                raise ConfigError(
                    f"links.{hop}", f"unknown profile {name!r}; allowed: {', '.join(sorted(available))}"
                )

    def profiles(self) -> dict[str, LinkProfile]:
        return {hop: profile(getattr(self, hop)) for hop in keys.HOPS}


RecordLevel = Literal["none", "control", "all"]
RECORD_LEVELS: tuple[RecordLevel, ...] = typing.get_args(RecordLevel)


@dataclass(frozen=True)
class RecordConfig:
    """The bus recording (abyss.recording.store): what each station sent and received."""

    level: RecordLevel = "all"  # none | control (what is not bulk) | all
    directory: str = ""  # where each station writes <station>.mcap; "" records nothing (`abyss up` sets it)
    max_rate_hz: float = 50.0  # per key and direction: the rest is skipped and counted
    bulk_max_rate_hz: float = 2.0  # the same for images, clouds, the scene stream

    def __post_init__(self) -> None:
        one_of("record.level", self.level, RECORD_LEVELS)
        positive("record.max_rate_hz", self.max_rate_hz)
        positive("record.bulk_max_rate_hz", self.bulk_max_rate_hz)


MIN_CPU_CORES = 0.05  # a cap below this leaves a station too little to stop within its bound


@dataclass(frozen=True)
class CpuConfig:
    """A CPU cap per station [cores], the paper's processing power beside bandwidth, delay and
    sensor noise (`abyss up --cpu STATION=CORES`): a cgroup quota on Linux, `cpus:` in compose.
    0 leaves the station uncapped; a capped station sheds its oldest frames, and says so."""

    simulation: float = 0.0
    onboard: float = 0.0
    vessel: float = 0.0
    onshore: float = 0.0

    def __post_init__(self) -> None:
        for name, cores in dataclasses.asdict(self).items():
            if cores != 0.0 and not MIN_CPU_CORES <= cores <= 1024:
                raise ConfigError(f"cpu.{name}", f"{cores} cores: 0 (uncapped) or {MIN_CPU_CORES} to 1024")

    def capped(self) -> dict[str, float]:
        """The capped stations and their caps [cores]."""
        return {name: cores for name, cores in dataclasses.asdict(self).items() if cores}


TimeMode = Literal["real", "sim", "lockstep"]
TIME_MODES: tuple[TimeMode, ...] = typing.get_args(TimeMode)


@dataclass(frozen=True)
class TimeConfig:
    """The system's time source (timing.clock): `real` (the wall clock; the only mode with a real
    component, real links or an operator in the loop), `sim` (the simulation's clock drives every
    station's rates and timers and every emulated link, `speed` simulated seconds per wall
    second, or `max`: as fast as the slowest station allows) or `lockstep` (the same, one control
    period at a time, each station's loops one at a time: a run repeats bit for bit,
    timing.lockstep)."""

    mode: TimeMode = "real"
    speed: str = "1"  # a positive number, or "max"
    max_lag_s: float = 0.1  # [simulated s] how far a station's loops may be behind the simulation
    # the stations whose progress the simulation waits for, with `sim`
    stations: tuple[str, ...] = ("onboard", "vessel", "onshore")
    # lockstep: the simulation stops advancing at this simulated time (abyss up's --duration), so
    # that a run ends on the same period whenever it is stopped; 0: never
    end_s: float = 0.0
    # lockstep: simulated times at which the simulation holds, before their period, until the
    # testbed releases it (the scenario runner's timed events: a fault, a link change, a station
    # killed and restarted, each landing on its period; timing.lockstep_testbed, Holds)
    holds_s: tuple[float, ...] = ()
    # lockstep: the testbed adds holds during the run as well (the scenario runner's events timed on
    # an intervention's phase), and the simulation runs only the periods the runner leases it
    # meanwhile (timing.lockstep, PHASE_LEASE)
    phase_holds: bool = False

    def __post_init__(self) -> None:
        one_of("time.mode", self.mode, TIME_MODES)
        if self.holds_s and self.mode != "lockstep":
            raise ConfigError("time.holds_s", f"only with time.mode lockstep ({self.mode} has no holds)")
        if self.phase_holds and self.mode != "lockstep":
            raise ConfigError("time.phase_holds", f"only with time.mode lockstep ({self.mode} has no holds)")
        for hold_s in self.holds_s:
            positive("time.holds_s", hold_s, allow_zero=True)
        if self.speed != "max":
            try:
                speed = float(self.speed)
            except ValueError:
                speed = math.nan
            if not math.isfinite(speed) or not 0.01 <= speed <= 1000:
                raise ConfigError("time.speed", f"{self.speed!r}: a number from 0.01 to 1000, or max")
        if self.mode != "sim" and self.speed_factor != 1.0:
            raise ConfigError(
                "time.speed",
                f"{self.speed}: only with time.mode sim ({self.mode} runs at "
                f"{'1' if self.mode == 'real' else 'the speed its slowest station allows'})",
            )
        positive("time.end_s", self.end_s, allow_zero=True)
        positive("time.max_lag_s", self.max_lag_s, allow_zero=True)
        for station in self.stations:
            if station not in keys.STATIONS or station == "simulation":
                raise ConfigError("time.stations", f"{station!r}: not one of onboard, vessel, onshore")

    @property
    def speed_factor(self) -> float:
        """Simulated seconds per wall second asked for (inf: max)."""
        return math.inf if self.speed == "max" else float(self.speed)

    @property
    def simulated(self) -> bool:
        """On the simulation's clock: `sim` or `lockstep`."""
        return self.mode != "real"


# the stations a ROS 2 node can stand for (ros2.gateway); "": none
Ros2Station = Literal["", "onboard", "vessel", "simulation"]
ROS2_STATIONS: tuple[Ros2Station, ...] = typing.get_args(Ros2Station)[1:]
_ROS_NAMESPACE = re.compile(r"^(/[A-Za-z_][A-Za-z0-9_]*)+$")


@dataclass(frozen=True)
class Ros2Config:
    """The ROS 2 gateway (abyss.ros2.gateway): a ROS 2 node over rmw_zenoh in a station's place."""

    station: Ros2Station = ""  # the station the gateway stands for (`abyss up --ros2 STATION`); "" none
    domain: int = 0  # ROS_DOMAIN_ID: the first chunk of every rmw_zenoh key
    namespace: str = "/abyss"  # the gateway's topics: <namespace>/<station>/<topic>
    # the Zenoh router the ROS 2 nodes connect to: the gateway listens as one (rmw_zenohd's default
    # endpoint) or, with `connect`, joins one that runs already (rmw_zenohd)
    listen: tuple[str, ...] = ("tcp/127.0.0.1:7447",)
    connect: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.station not in ("", *ROS2_STATIONS):
            raise ConfigError(
                "ros2.station", f"{self.station!r}: a ROS 2 node can stand for {', '.join(ROS2_STATIONS)}"
            )
        if not 0 <= self.domain <= 232:
            raise ConfigError("ros2.domain", f"{self.domain}: a ROS domain id is 0 to 232")
        if not _ROS_NAMESPACE.match(self.namespace):
            raise ConfigError(
                "ros2.namespace",
                f"{self.namespace!r} is not an absolute ROS 2 namespace such as /abyss or /team/rov1",
            )
        if not self.listen and not self.connect:
            raise ConfigError(
                "ros2.listen", "empty, and so is ros2.connect: the ROS 2 nodes would have no router"
            )


Box = tuple[float, float, float, float, float, float]


@dataclass(frozen=True)
class MissionConfig:
    # rows of x, y, z [m, world] and yaw [rad]
    # the last, 1.8 m off the panel's face and level with its middle: the arm reaches the
    # valves above and the levers below without the vehicle moving
    waypoints: tuple[tuple[float, float, float, float], ...] = (
        (1.5, 0.0, -7.0, 0.0),
        (2.5, 0.8, -7.6, 0.3),
        (3.2, 0.0, -8.0, 0.0),
    )
    position_tolerance_m: float = 0.15
    heading_tolerance_rad: float = 0.1
    # [m] the mission is done only with the vehicle this close to its last waypoint (the waypoints
    # are reached at position_tolerance_m): a whole-body vehicle, moved off its mark by its arm's
    # interventions, flies back onto it first
    done_position_tolerance_m: float = 0.05
    # [s] a waypoint not reached within its leg flown at onboard's speed limits (its length over
    # max_speed_mps, its turn over max_yaw_rate_radps) plus this is missed: onboard holds it and
    # reports the mode "missed", and the mission is not done; 0: no limit
    waypoint_timeout_s: float = 30.0
    # the end-effector's goal once the last waypoint is reached: x, y, z [m, world], roll, pitch,
    # yaw [rad] (rotations about the world's x, y, z, in that order); empty: no arm goal. E.g.
    # [4.86, 0, -8.35, 1.5708, 0, 0]: the fingers either side of the middle valve's handle.
    arm_target: tuple[float, ...] = ()
    # or the interventions, one after the other once the last waypoint is reached: rows of a part
    # of the panel and what to do with it: a valve and the angle to turn it by [deg], or a lever
    # and the stop to throw it to (up, down); the success of each is judged on the simulation's truth
    interventions: tuple[tuple[str, str], ...] = (("valve_1", "90"), ("lever_0", "down"))
    arm_position_tolerance_m: float = 0.005
    arm_orientation_tolerance_rad: float = 0.02
    arm_settle_s: float = 2.0  # [s] within both tolerances this long: the goal is reached
    # boxes the arm keeps clear of: centre x, y, z and half sizes [m, world]
    obstacles: tuple[Box, ...] = (
        (5.0, 0.0, -8.6, 0.05, 0.8, 0.6),  # the panel's plate
        (5.0, 0.0, -20.0, 50.0, 50.0, 10.0),  # the seabed around the panel, a floor at z = -10 m
    )
    resend_period_s: float = 2.0  # [s] shore resends a command until onboard acknowledges it
    # onboard refuses a waypoint closer than this to an obstacle or the surface, and an arm
    # goal out of the arm's reach from where the vehicle will be [m]
    vehicle_clearance_m: float = 0.5

    def __post_init__(self) -> None:
        if not 1 <= len(self.waypoints) <= 1000:
            raise ConfigError("mission.waypoints", "needs 1 to 1000 rows of [x, y, z, yaw]")
        if len(self.arm_target) not in (0, 6):
            raise ConfigError("mission.arm_target", "needs [x, y, z, roll, pitch, yaw], or [] for none")
        if self.arm_target and self.interventions:
            raise ConfigError(
                "mission.interventions",
                "an arm goal (mission.arm_target) or interventions, not both: set the other to []",
            )
        for i, (_, amount) in enumerate(self.interventions):  # the parts are the site's: Config checks them
            try:
                intent_of(amount)
            except BadInput as exc:
                raise ConfigError(f"mission.interventions[{i}]", str(exc)) from None
        positive("mission.waypoint_timeout_s", self.waypoint_timeout_s, allow_zero=True)
        for name in (
            "position_tolerance_m",
            "done_position_tolerance_m",
            "heading_tolerance_rad",
            "arm_position_tolerance_m",
            "arm_orientation_tolerance_rad",
            "arm_settle_s",
            "resend_period_s",
            "vehicle_clearance_m",
        ):
            positive(f"mission.{name}", getattr(self, name))
        for i, box in enumerate(self.obstacles):
            for size in box[3:]:
                positive(f"mission.obstacles[{i}] half size", size)

    def arm_goal(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The end-effector goal as position [m, world] and quaternion (w, x, y, z), or None."""
        if not self.arm_target:
            return None
        x, y, z, roll, pitch, yaw = self.arm_target
        return np.array([x, y, z]), quat_wxyz_of(rotation_of_rpy(roll, pitch, yaw))
