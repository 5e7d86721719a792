"""The robot as data: a package (a directory) holding its model file and `robot.toml`, which names
what every station learns from it, as ROS nodes learn it from `robot_description`: the model
(`[model]`: the file, MJCF today, and its floating base), the arm (`[arm]`: its joints in chain
order, the end-effector site, the stowed pose, the bodies kept clear of obstacles; `[arm.gripper]`:
its kind, joints and full opening), the cameras (`[cameras]`: their names, the stereo pair, the
depth camera), the navigation sensors (`[nav_sensors]`), and the vehicle's marine model and
thrusters (`[added_mass]`, `[damping]`, `[buoyancy]`, `[thrusters]`, which
stations/simulation/hydrodynamics.py reads).

`load_robot` reads a package through the one typed reader (common.reading) and holds it against
its compiled model: a joint, site, body, camera or thruster the model lacks, an added mass that is
not positive definite, a thruster layout that cannot move the vehicle in heave or a stowed pose of
the wrong length is refused with a ConfigError naming robot.toml and the field. `robot_of(config)`
is the one way a station gets the robot it runs (`simulation.robot`; "" the shipped one), loaded
once per package."""

from __future__ import annotations

import functools
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from abyss.common.errors import ConfigError
from abyss.common.reading import read_table
from abyss.description.marine import VehicleModel, marine_model
from abyss.description.models import package_dir
from abyss.description.robot_file import (
    PUBLISHED_FIGURES,
    NavSensorsSection,
    RobotFile,
)
from abyss.description.urdf import refuse_in_mjcf, urdf_spec, write_mjcf

if TYPE_CHECKING:
    import mujoco


ROBOTS_DIR = Path(__file__).parent / "models" / "robots"
SHIPPED_ROBOT_DIR = ROBOTS_DIR / "workclass"  # the testbed's own work-class ROV
ROBOT_FILE_NAME = "robot.toml"
# the body wrench's rows (fx, fy, fz, mx, my, mz) the vehicle's velocity reference commands, in
# order (surge, sway, heave, yaw); roll and pitch are left to the hydrostatic restoring moment
COMMANDED_AXES = (0, 1, 2, 5)
AXIS_NAMES = ("surge", "sway", "heave", "roll", "pitch", "yaw")
HEAVE = 2


@dataclass(frozen=True)
class Robot:
    """A loaded robot package: its names, frames and paths, held against its model."""

    directory: Path
    spec: RobotFile
    marine: VehicleModel  # the marine model and thrusters, typed once (description/marine.py)
    # (6, n): the body wrench about the base's centre of mass per newton of each thruster, in
    # `thrusters`' order (thrust_matrix): the one allocation matrix the simulation and the check use
    allocation: np.ndarray
    actuated_axes: tuple[int, ...]  # rows of the body wrench the thrusters move, of COMMANDED_AXES
    # between the fingers' faces with each at zero travel [m]: what a handle of this thickness
    # leaves of the opening where they meet it (the opening is the travel, summed)
    closed_gap_m: float = 0.0
    mass_kg: float = 0.0  # the base with all it carries (its subtree), as the model compiles it
    yaw_inertia_kg_m2: float = 0.0  # the base body's own, about its principal z
    has_sonar: bool = True  # the model has the sonar's site (`[sonar] site`)

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def file(self) -> Path:
        """robot.toml: its sections, the marine model and thrusters among them."""
        return self.directory / ROBOT_FILE_NAME

    @property
    def model_file(self) -> Path:
        return self.directory / self.spec.model.file

    @property
    def base(self) -> str:
        return self.spec.model.base

    @property
    def arm_joints(self) -> tuple[str, ...]:
        return self.spec.arm.joints

    @property
    def gripper_joints(self) -> tuple[str, ...]:
        return self.spec.arm.gripper.joints

    @property
    def end_effector_site(self) -> str:
        return self.spec.arm.end_effector_site

    @property
    def stowed_rad(self) -> tuple[float, ...]:
        return self.spec.arm.stowed_rad

    @property
    def clearance_points(self) -> tuple[str, ...]:
        """The arm's frames kept clear of obstacles: its clearance bodies, then the end effector."""
        return (*self.spec.arm.clearance_bodies, self.end_effector_site)

    @property
    def cameras(self) -> tuple[str, ...]:
        return self.spec.cameras.names

    @property
    def stereo_left(self) -> str:
        return self.spec.cameras.stereo[0]

    @property
    def stereo_right(self) -> str:
        return self.spec.cameras.stereo[1]

    @property
    def depth_camera(self) -> str:
        return self.spec.cameras.depth

    def camera_topic(self, camera: str) -> str:
        """The topic a camera's images go out on, by its role (interface.keys: the key table names
        roles, not a robot's cameras): camera/left, camera/right or camera/depth."""
        roles = {self.stereo_left: "left", self.stereo_right: "right", self.depth_camera: "depth"}
        return f"camera/{roles[camera]}"

    @property
    def nav_sensors(self) -> NavSensorsSection:
        return self.spec.nav_sensors

    @property
    def nav_sensor_names(self) -> tuple[str, ...]:
        return self.spec.nav_sensors.names

    @property
    def sonar_site(self) -> str:
        return self.spec.sonar.site

    @property
    def thrusters(self) -> tuple[str, ...]:
        return self.spec.thrusters.names

    @property
    def shipped(self) -> bool:
        return self.directory == SHIPPED_ROBOT_DIR.resolve()


def robot_at(package: str) -> Robot:
    """The robot package at `package` (a directory's path, or a shipped package's name; "" the
    shipped default), loaded once."""
    return load_robot(package_dir("robot", package) if package else SHIPPED_ROBOT_DIR)


def load_robot(directory: Path) -> Robot:
    """The robot package in `directory` (robot.toml and the model it names), checked against
    the compiled model; ConfigError naming the file and the field for a bad one. Cached per
    package (its resolved path)."""
    return _load(Path(directory).expanduser().resolve())


@functools.cache
def _load(directory: Path) -> Robot:
    path = directory / ROBOT_FILE_NAME
    try:
        table = tomllib.loads(path.read_text())
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise ConfigError("simulation.robot", f"cannot read {path}: {exc}") from None
    try:
        spec: RobotFile = read_table(RobotFile, table)
    except ConfigError as exc:
        raise ConfigError(exc.field, exc.reason, str(path)) from None
    _check_published(spec, path)
    model = _compiled(directory, spec, path)
    checks = (_check_distinct, _check_model_names, _check_arm, _check_cameras)
    for check in checks:
        check(model, spec, path)
    marine = marine_model(spec, path)
    has_sonar = _has(model, "site", spec.sonar.site)
    if "sonar" in table and not has_sonar:  # named, and not there (else: a robot without a sonar)
        _require(model, path, "sonar.site", "site", (spec.sonar.site,))
    allocation = thrust_matrix(model, spec.model.base, spec.thrusters.names, path)
    base = model.body(spec.model.base).id
    allocation.flags.writeable = False
    return Robot(
        directory,
        spec,
        marine,
        allocation,
        actuated_axes(allocation, path),
        closed_gap_m(model, spec.arm.gripper.joints),
        float(model.body_subtreemass[base]),
        float(model.body_inertia[base][2]),
        has_sonar,
    )


def closed_gap_m(model: mujoco.MjModel, fingers: tuple[str, ...]) -> float:
    """The least distance between the first two fingers' colliding geoms at zero travel (the
    model's reference pose) [m], as MuJoCo measures it; 0 where a finger has none."""
    import mujoco

    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    colliding = [
        [
            g
            for g in range(model.ngeom)
            if model.geom_bodyid[g] == body and (model.geom_contype[g] or model.geom_conaffinity[g])
        ]
        for body in (model.joint(name).bodyid[0] for name in fingers[:2])
    ]
    if len(colliding) < 2 or not all(colliding):
        return 0.0
    return min(
        float(mujoco.mj_geomDistance(model, data, a, b, 1.0, None))
        for a in colliding[0]
        for b in colliding[1]
    )


def _compiled(directory: Path, spec: RobotFile, path: Path) -> mujoco.MjModel:
    try:
        return model_spec(directory, spec, path).compile()
    except ValueError as exc:  # MuJoCo's compiler's error
        raise ConfigError(
            "model.file", f"{directory / spec.model.file} does not compile: {exc}", str(path)
        ) from None


def model_spec(directory: Path, spec: RobotFile, path: Path) -> mujoco.MjSpec:
    """The package's model as a MuJoCo spec (its MJCF, parsed; or its URDF with what robot.toml
    adds, description/urdf.py); ConfigError naming robot.toml's `model.file` for one missing or
    unreadable."""
    import mujoco

    if spec.model.format == "urdf":
        return urdf_spec(directory, spec, path)
    refuse_in_mjcf(spec.model, path)
    model_file = directory / spec.model.file
    if not model_file.is_file():
        raise ConfigError("model.file", f"no such file: {model_file}", str(path))
    try:
        return mujoco.MjSpec.from_file(str(model_file))
    except ValueError as exc:  # MuJoCo's parser's error
        raise ConfigError("model.file", f"{model_file} does not parse: {exc}", str(path)) from None


def robot_spec(robot: Robot) -> mujoco.MjSpec:
    """A fresh spec of the robot's model, to compose a world from (description.site)."""
    return model_spec(robot.directory, robot.spec, robot.file)


def robot_mjcf(robot: Robot) -> Path:
    """The MJCF of the robot alone that Pinocchio reads (its MJCF parser takes no height fields,
    so never a world's): an MJCF package's own file, a URDF package's model written to the cache."""
    if robot.spec.model.format == "urdf":
        return write_mjcf(robot.directory, robot.spec, robot.file)
    return robot.model_file


def _has(model: mujoco.MjModel, kind: str, name: str) -> bool:
    import mujoco

    return bool(mujoco.mj_name2id(model, getattr(mujoco.mjtObj, f"mjOBJ_{kind.upper()}"), name) >= 0)


COUNTS = {"joint": "njnt", "site": "nsite", "body": "nbody", "camera": "ncam", "actuator": "nu"}


def _names(model: mujoco.MjModel, kind: str) -> list[str]:
    """The model's named elements of `kind` (joint, site, body, camera, actuator), in order."""
    import mujoco

    obj = getattr(mujoco.mjtObj, f"mjOBJ_{kind.upper()}")
    named = (mujoco.mj_id2name(model, obj, i) for i in range(getattr(model, COUNTS[kind])))
    return [name for name in named if name]


def _require(model: mujoco.MjModel, path: Path, where: str, kind: str, names: tuple[str, ...]) -> None:
    missing = [n for n in names if not _has(model, kind, n)]
    if missing:
        there = _names(model, kind)
        shown = ", ".join(there[:40]) + (f" and {len(there) - 40} more" if len(there) > 40 else "")
        raise ConfigError(
            where,
            f"{', '.join(missing)}: no {kind} of that name in the model (its {kind}s: {shown or 'none'})",
            str(path),
        )


def _check_distinct(model: mujoco.MjModel, spec: RobotFile, path: Path) -> None:
    s = spec.nav_sensors
    lists = {
        "arm.joints": spec.arm.joints,
        "arm.gripper.joints": spec.arm.gripper.joints,
        "thrusters.names": spec.thrusters.names,
        "cameras.names": spec.cameras.names,
        "nav_sensors": (s.usbl, s.depth, s.dvl, s.imu),
    }
    for where, names in lists.items():
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise ConfigError(where, f"{', '.join(twice)} named more than once", str(path))


def _check_model_names(model: mujoco.MjModel, spec: RobotFile, path: Path) -> None:
    import mujoco

    base = spec.model.base
    _require(model, path, "model.base", "body", (base,))
    _require(model, path, "model.base", "joint", (base,))
    if model.jnt_type[model.joint(base).id] != mujoco.mjtJoint.mjJNT_FREE:
        raise ConfigError("model.base", f"joint {base!r} is not a free joint", str(path))
    _require(model, path, "thrusters.names", "site", spec.thrusters.names)
    _require(model, path, "thrusters.names", "actuator", spec.thrusters.names)


def _check_arm(model: mujoco.MjModel, spec: RobotFile, path: Path) -> None:
    arm = spec.arm
    if not arm.joints:
        raise ConfigError("arm.joints", "needs the arm's joints, in chain order", str(path))
    for where, names in (("arm.joints", arm.joints), ("arm.gripper.joints", arm.gripper.joints)):
        _require(model, path, where, "joint", names)
        _require(model, path, where, "actuator", names)
    _require(model, path, "arm.end_effector_site", "site", (arm.end_effector_site,))
    _require(model, path, "arm.clearance_bodies", "body", arm.clearance_bodies)
    if len(arm.stowed_rad) != len(arm.joints):
        raise ConfigError(
            "arm.stowed_rad", f"{len(arm.stowed_rad)} angles for {len(arm.joints)} joints", str(path)
        )
    for name, angle_rad in zip(arm.joints, arm.stowed_rad, strict=True):
        joint = model.joint(name)
        lo, hi = joint.range
        if joint.limited[0] and not lo <= angle_rad <= hi:
            raise ConfigError(
                "arm.stowed_rad", f"{name} at {angle_rad} rad: outside [{lo:.4g}, {hi:.4g}]", str(path)
            )
    if not 0.0 < arm.gripper.opening_m <= sum(model.joint(n).range[1] for n in arm.gripper.joints) + 1e-9:
        raise ConfigError(
            "arm.gripper.opening_m",
            f"{arm.gripper.opening_m} m: needs a positive opening within the fingers' travel",
            str(path),
        )


def _check_published(spec: RobotFile, path: Path) -> None:
    """`[published]`: `source` (text) and figures abyss knows, each a positive number."""
    for name, value in spec.published.items():
        if name == "source":
            if not isinstance(value, str):
                raise ConfigError("published.source", "text: where the figures come from", str(path))
        elif name not in PUBLISHED_FIGURES:
            raise ConfigError(
                f"published.{name}",
                f"not a figure abyss knows: one of source, {', '.join(PUBLISHED_FIGURES)}",
                str(path),
            )
        elif isinstance(value, str) or not value > 0:
            raise ConfigError(
                f"published.{name}", f"{value!r}: a positive number ({PUBLISHED_FIGURES[name]})", str(path)
            )


def _check_cameras(model: mujoco.MjModel, spec: RobotFile, path: Path) -> None:
    cameras = spec.cameras
    _require(model, path, "cameras.names", "camera", cameras.names)
    for where, names in (("cameras.stereo", cameras.stereo), ("cameras.depth", (cameras.depth,))):
        strays = [n for n in names if n not in cameras.names]
        if strays:
            raise ConfigError(where, f"{', '.join(strays)} not one of {', '.join(cameras.names)}", str(path))
    if cameras.stereo[0] == cameras.stereo[1]:
        raise ConfigError("cameras.stereo", "needs two cameras, left then right", str(path))
    unnamed = [n for n in _names(model, "camera") if n not in cameras.names]
    if unnamed:  # it would never render: taken silently, a camera meant for the pair looks lost
        raise ConfigError(
            "cameras.names",
            f"the model's camera {', '.join(unnamed)} is not named here: every camera of the model is "
            "the stereo pair's left or right or the depth camera (or leave it out of the model)",
            str(path),
        )
    roleless = [n for n in cameras.names if n not in (*cameras.stereo, cameras.depth)]
    if roleless:
        raise ConfigError(
            "cameras.names",
            f"{', '.join(roleless)}: each camera is the stereo pair's left or right or the depth camera "
            "(published on camera/left, camera/right, camera/depth)",
            str(path),
        )


def thrust_matrix(
    model: mujoco.MjModel, body: str, names: tuple[str, ...], path: Path | None = None
) -> np.ndarray:
    """(6, n): the body wrench about `body`'s centre of mass per newton of each thruster, each
    pushing along its site's z axis; ConfigError (naming `path`) for a site not on `body`."""
    import mujoco

    b = model.body(body).id
    com = model.body_ipos[b]
    columns = []
    for name in names:
        site = model.site(name)
        if site.bodyid[0] != b:
            raise ConfigError("thrusters.names", f"{name} is not on {body}", str(path or ""))
        rotation = np.empty(9)
        mujoco.mju_quat2Mat(rotation, site.quat)
        axis = rotation.reshape(3, 3)[:, 2]
        columns.append(np.r_[axis, np.cross(site.pos - com, axis)])
    return np.array(columns).T


def actuated_axes(allocation: np.ndarray, path: Path | None = None) -> tuple[int, ...]:
    """The wrench rows of COMMANDED_AXES the thrusters move independently: each in turn where it
    adds to the rank of the rows taken before it. ConfigError (naming `path`) where heave is not
    among them: a vehicle that cannot change depth cannot fly a mission."""
    taken: list[int] = []
    for axis in COMMANDED_AXES:
        if np.linalg.matrix_rank(allocation[[*taken, axis]]) > len(taken):
            taken.append(axis)
    if HEAVE not in taken:
        moved = ", ".join(AXIS_NAMES[a] for a in taken) or "nothing"
        raise ConfigError(
            "thrusters.names",
            f"the thrusters cannot move the vehicle in heave (they move {moved})",
            str(path or ""),
        )
    return tuple(taken)


def place_at_start(
    model: Any, qpos: Any, robot: Robot, position_m_world: tuple[float, float, float], yaw_rad: float
) -> None:
    """A world's first positions in `qpos` (a MuJoCo model's of the world with `robot` in it): the
    vehicle at `position_m_world` [m] heading `yaw_rad` [rad] about the world's z, level, the arm
    stowed."""
    p = model.joint(robot.base).qposadr[0]
    qpos[p : p + 3] = position_m_world
    qpos[p + 3 : p + 7] = [np.cos(yaw_rad / 2), 0.0, 0.0, np.sin(yaw_rad / 2)]
    for name, angle_rad in zip(robot.arm_joints, robot.stowed_rad, strict=True):
        qpos[model.joint(name).qposadr[0]] = angle_rad
