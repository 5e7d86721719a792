"""robot.toml as data: its sections typed, as the one typed reader (common.reading) reads them, before
anything is compiled. The robot (description/robot.py) holds them against the model; a URDF's own
sections (its sites, cameras and servos, which a URDF cannot say) are composed into MJCF by
description/urdf.py; the marine sections (`[added_mass]`, `[damping]`, `[buoyancy]`,
`[thrusters]`) are typed into the marine model once (description/robot.py: `Robot.marine`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal


@dataclass(frozen=True)
class SiteSection:
    """A site on a link of the URDF: a thruster's (it pushes along the site's z), a sensor's,
    the end effector's. Orientation as MJCF's: `zaxis`, or `xyaxes` (its x then its y), in the
    link's frame; neither: the link's."""

    name: str
    link: str
    position_m: tuple[float, float, float] = (0.0, 0.0, 0.0)  # in the link's frame [m]
    zaxis: tuple[float, float, float] | None = None
    xyaxes: tuple[float, float, float, float, float, float] | None = None
    size_m: float = 0.01  # drawn as a sphere of this radius where site group 3 is shown [m]


@dataclass(frozen=True)
class CameraSection:
    """A camera on a link of the URDF, as MJCF's: it looks along its -z, `xyaxes` its x (the
    image's right) and its y (the image's up) in the link's frame."""

    name: str
    link: str
    position_m: tuple[float, float, float]  # in the link's frame [m]
    xyaxes: tuple[float, float, float, float, float, float]
    fovy_deg: float = 60.0  # vertical field of view [deg]


@dataclass(frozen=True)
class JointServo:
    """One joint's servo where the URDF's limits are not the ones wanted (or are missing)."""

    kv: float | None = None  # the gain [N m s/rad] or [N s/m]; None: the section's
    force_max: float | None = None  # [N m] or [N]; None: the URDF joint's effort limit
    speed_max: float | None = None  # [rad/s] or [m/s]; None: the URDF joint's velocity limit


@dataclass(frozen=True)
class ServosSection:
    """The velocity servos, one per arm and gripper joint, named as the joint: torque =
    kv (ctrl - qdot) within the force limit, ctrl within the speed limit."""

    arm_kv: float = 400.0  # [N m s/rad]
    gripper_kv: float = 1000.0  # [N s/m]
    # the motors' inertia reflected through their gears onto the joints: a light arm's links
    # alone are too light for a stiff servo at the physics step
    arm_armature: float = 0.0  # [kg m^2]
    gripper_armature: float = 0.0  # [kg]
    joints: dict[str, JointServo] = field(default_factory=dict)  # by joint name


@dataclass(frozen=True)
class ModelSection:
    file: str  # the model file, relative to the package
    format: Literal["mjcf", "urdf"] = "mjcf"  # urdf: *.urdf, or xacro (description/urdf.py)
    base: str = "vehicle"  # the floating base: its body, and its free joint, of this name
    # a URDF's alone (description/urdf.py): what the simulation needs that a URDF cannot say
    xacro_args: dict[str, str | bool | int | float] = field(default_factory=dict)
    wet_links: tuple[str, ...] | None = None  # whose collision geoms are wet; None: every link's
    sites: tuple[SiteSection, ...] = ()
    cameras: tuple[CameraSection, ...] = ()
    servos: ServosSection = field(default_factory=ServosSection)


@dataclass(frozen=True)
class GripperSection:
    kind: Literal["parallel"]  # two fingers sliding apart: the opening is their travel summed
    joints: tuple[str, ...]  # the fingers' slide joints (each driven by an actuator of its name)
    opening_m: float  # the full opening: the fingers' travel at their upper limits, summed [m]


@dataclass(frozen=True)
class ArmSection:
    joints: tuple[str, ...]  # in chain order, base to tool (each driven by an actuator of its name)
    end_effector_site: str
    stowed_rad: tuple[float, ...]  # one per joint [rad]
    gripper: GripperSection
    clearance_bodies: tuple[str, ...] = ()  # kept clear of obstacles, with the end effector


@dataclass(frozen=True)
class CamerasSection:
    names: tuple[str, ...]  # every camera, in the order they are published
    stereo: tuple[str, str]  # left, right
    depth: str  # the range camera (rendered as depth, the others as RGB)


@dataclass(frozen=True)
class NavSensorsSection:
    """The navigation sensors' names (as faults target them), one per kind the simulation has."""

    usbl: str = "usbl"
    depth: str = "depth"  # the pressure sensor
    dvl: str = "dvl"
    imu: str = "imu"

    @property
    def names(self) -> tuple[str, ...]:
        return (self.usbl, self.depth, self.dvl, self.imu)


@dataclass(frozen=True)
class SonarSection:
    """The imaging sonar (stations/simulation/sonar.py): the site it pings from, its x axis the
    boresight, its z axis up (the beams fan out in the site's xy plane)."""

    site: str = "sonar"


@dataclass(frozen=True)
class ThrustersSection:
    names: tuple[str, ...]  # the model's thruster sites and motors, in allocation order
    time_constant_s: float
    deadband: float
    forward_max_n: float
    reverse_max_n: float


# what a `[published]` table may hold besides `source` (where the figures come from, with the
# conditions they were taken in: the battery's voltage, a tether): each figure's meaning, all
# positive numbers; `abyss robot check` holds the simulated ones to them (validation/robot/check.py)
PUBLISHED_FIGURES = {
    "mass_kg": "the mass in air [kg], the arm's included",
    "surge_max_mps": "the top speed ahead [m/s]",
    "surge_reverse_max_mps": "the top speed astern [m/s]",
    "sway_max_mps": "the top speed to port [m/s]",
    "sway_reverse_max_mps": "the top speed to starboard [m/s]",
    "heave_max_mps": "the top speed up [m/s]",
    "heave_reverse_max_mps": "the top speed down [m/s]",
    "yaw_max_degps": "the top turn rate, the slower way [deg/s]",
    "bollard_forward_n": "the bollard pull ahead [N]",
    "bollard_lateral_n": "the bollard pull to port [N]",
    "bollard_vertical_n": "the bollard pull up [N]",
}


@dataclass(frozen=True)
class RobotFile:
    """robot.toml, its sections typed; the marine ones' numbers are hydrodynamics.py's to read."""

    name: str
    source: str
    model: ModelSection
    arm: ArmSection
    cameras: CamerasSection
    thrusters: ThrustersSection
    added_mass: dict[str, Any]
    damping: dict[str, Any]
    buoyancy: dict[str, Any]
    nav_sensors: NavSensorsSection = field(default_factory=NavSensorsSection)
    sonar: SonarSection = field(default_factory=SonarSection)
    # figures published for the vehicle (`source` names where), held to the simulated ones by
    # `abyss robot check` (validation/robot/check.py, which lists the names it knows)
    published: dict[str, float | str] = field(default_factory=dict)
    # a partial configuration for flying this robot (its controllers' gains, its speed limits),
    # layered under the site's and the user's (config: load)
    config: dict[str, Any] = field(default_factory=dict)
