"""The robot package (description/robot.py): the shipped one loads with the names the stations used to
hold as constants, each kind of broken package is refused at load naming robot.toml and the field,
and no module of the package names the shipped robot's joints, thrusters, cameras or sites."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import pytest

from abyss.common.errors import ConfigError
from abyss.config import Config, load, robot_of
from abyss.description.robot import SHIPPED_ROBOT_DIR, load_robot, robot_at
from abyss.description.site import site_at

ROOT = Path(__file__).resolve().parents[2]


def test_the_shipped_robot_loads_with_its_names() -> None:
    robot = robot_at("")
    assert robot is robot_of(Config()) is load_robot(SHIPPED_ROBOT_DIR)  # loaded once per package
    assert robot.shipped and robot.model_file == SHIPPED_ROBOT_DIR.resolve() / "robot.xml"
    assert robot.arm_joints == (
        "shoulder_yaw",
        "shoulder_pitch",
        "elbow",
        "wrist_roll",
        "wrist_pitch",
        "tool_roll",
    )
    assert robot.gripper_joints == ("finger_left", "finger_right")
    assert robot.stowed_rad == (0.0, 1.3, -2.4, 0.0, 1.1, 0.0)
    assert robot.end_effector_site == "ee"
    assert robot.clearance_points == ("arm_link3", "arm_link5", "ee")
    assert robot.thrusters == ("thr_fl", "thr_fr", "thr_rl", "thr_rr", "thr_vl", "thr_vr")
    assert robot.cameras == ("cam_left", "cam_right", "cam_depth")
    assert (robot.stereo_left, robot.stereo_right, robot.depth_camera) == (
        "cam_left",
        "cam_right",
        "cam_depth",
    )
    assert robot.nav_sensor_names == ("usbl", "depth", "dvl", "imu")
    assert robot.actuated_axes == (0, 1, 2, 5)  # surge, sway, heave, yaw: from the layout's rank


def test_simulation_robot_names_a_package_and_is_checked_at_start(tmp_path: Path) -> None:
    package = _copy(tmp_path)
    config = load(overrides=[f"simulation.robot={package}"])
    assert config.simulation.robot == str(package.resolve())
    assert robot_of(config).directory == package.resolve() and not robot_of(config).shipped
    with pytest.raises(ConfigError, match=r"simulation\.robot: .*not a robot package"):
        load(overrides=[f"simulation.robot={tmp_path / 'nothing-here'}"])


def _copy(tmp_path: Path, name: str = "copy") -> Path:
    package = tmp_path / name
    shutil.copytree(SHIPPED_ROBOT_DIR, package)
    return package


def _broken(tmp_path: Path, old: str, new: str, file: str = "robot.toml") -> Path:
    """The shipped package copied with one thing changed (`old` to `new` in `file`)."""
    package = _copy(tmp_path, f"broken-{abs(hash((old, new, file)))}")
    path = package / file
    text = path.read_text()
    assert old in text, old
    path.write_text(text.replace(old, new, 1))
    return package


BROKEN = {  # one change each: (robot.toml's text, what it becomes, the field named, what is said)
    "a joint the model lacks": (
        '"shoulder_yaw", "shoulder_pitch"',
        '"shoulder_yaw", "shoulder_tilt"',
        "arm.joints",
        "shoulder_tilt",
    ),
    "a gripper joint the model lacks": (
        '"finger_left", "finger_right"',
        '"finger_left", "thumb"',
        "arm.gripper.joints",
        "thumb",
    ),
    "a thruster the model lacks": ('"thr_vl", "thr_vr"]', '"thr_vl", "thr_up"]', "thrusters.names", "thr_up"),
    "a camera the model lacks": (
        'names = ["cam_left", "cam_right", "cam_depth"]',
        'names = ["cam_left", "cam_right", "cam_sonar"]',
        "cameras.names",
        "cam_sonar",
    ),
    "a camera of the model left out of the names": (  # it was taken silently, and never rendered
        'names = ["cam_left", "cam_right", "cam_depth"]  # published in this order\n'
        'stereo = ["cam_left", "cam_right"]  # left, right: a 0.12 m baseline\ndepth = "cam_depth"',
        'names = ["cam_left", "cam_right"]\nstereo = ["cam_left", "cam_right"]\ndepth = "cam_right"',
        "cameras.names",
        "cam_depth is not named here",
    ),
    "a depth camera not among the cameras": (
        'depth = "cam_depth"',
        'depth = "cam_range"',
        "cameras.depth",
        "cam_range",
    ),
    "an end-effector site the model lacks": (
        'end_effector_site = "ee"',
        'end_effector_site = "tool"',
        "arm.end_effector_site",
        "tool",
    ),
    "a clearance body the model lacks": (
        '"arm_link3", "arm_link5"',
        '"arm_link3", "elbow_link"',
        "arm.clearance_bodies",
        "elbow_link",
    ),
    "a base the model lacks": ('base = "vehicle"', 'base = "hull"', "model.base", "hull"),
    "a stowed pose of the wrong length": (
        "stowed_rad = [0.0, 1.3, -2.4, 0.0, 1.1, 0.0]",
        "stowed_rad = [0.0, 1.3, -2.4]",
        "arm.stowed_rad",
        "3 angles for 6 joints",
    ),
    "a stowed pose past a joint's limit": (
        "stowed_rad = [0.0, 1.3, -2.4,",
        "stowed_rad = [0.0, 1.3, -3.0,",
        "arm.stowed_rad",
        "elbow",
    ),
    "an added mass not positive definite": (
        "diagonal = [1004.0, 1788.0, 1788.0,",
        "diagonal = [1004.0, 1788.0, 0.0,",
        "added_mass",
        "positive definite",
    ),
    "a sensor named twice": ('dvl = "dvl"', 'dvl = "usbl"', "nav_sensors", "usbl named more than once"),
    "an unknown gripper kind": ('kind = "parallel"', 'kind = "suction"', "arm.gripper.kind", "parallel"),
    "an unknown field": (
        "[arm.gripper]",
        "[arm.gripper]\nfingers = 2",
        "arm.gripper.fingers",
        "unknown field",
    ),
    "a missing model file": ('file = "robot.xml"', 'file = "rov.xml"', "model.file", "no such file"),
    "a gripper opening past the fingers' travel": (
        "opening_m = 0.08",
        "opening_m = 0.2",
        "arm.gripper.opening_m",
        "travel",
    ),
}


@pytest.mark.parametrize("case", sorted(BROKEN))
def test_a_broken_package_is_refused_naming_the_file_and_the_field(tmp_path: Path, case: str) -> None:
    old, new, field, said = BROKEN[case]
    package = _broken(tmp_path, old, new)
    with pytest.raises(ConfigError) as refused:
        load_robot(package)
    assert refused.value.source == str(package.resolve() / "robot.toml"), refused.value
    assert refused.value.field == field, refused.value
    assert said in refused.value.reason, refused.value


def test_a_thruster_layout_that_cannot_heave_is_refused(tmp_path: Path) -> None:
    """The vertical thrusters turned horizontal: the allocation's rank has no heave in it."""
    package = _broken(tmp_path, 'pos="0 0.4 0.1" zaxis="0 0 1"', 'pos="0 0.4 0.1" zaxis="1 0 0"', "robot.xml")
    xml = package / "robot.xml"
    xml.write_text(
        xml.read_text().replace('pos="0 -0.4 0.1" zaxis="0 0 1"', 'pos="0 -0.4 0.1" zaxis="1 0 0"')
    )
    with pytest.raises(ConfigError) as refused:
        load_robot(package)
    assert refused.value.source == str(package.resolve() / "robot.toml")
    assert refused.value.field == "thrusters.names"
    assert "cannot move the vehicle in heave (they move surge, sway, yaw)" in refused.value.reason


def test_a_layout_without_sway_drives_the_axes_it_has(tmp_path: Path) -> None:
    """The four vectored thrusters all pointed forward: surge, heave and yaw are left, not sway."""
    package = _copy(tmp_path, "no-sway")
    xml = package / "robot.xml"
    text = xml.read_text()
    for axis in ('zaxis="1 -1 0"', 'zaxis="1 1 0"'):
        text = text.replace(axis, 'zaxis="1 0 0"')
    xml.write_text(text)
    assert load_robot(package).actuated_axes == (0, 2, 5)


def test_a_robot_package_of_its_own_is_composed_into_the_site(tmp_path: Path) -> None:
    """Any package composes with the site (description.site): its base body first, so its free
    joint leads qpos; a package whose names clash with the site's is refused naming both."""
    from abyss.description.site import site_at, world_model

    package = _copy(tmp_path)
    world = world_model(load_robot(package), site_at(""))
    assert world.joint(world.jnt_qposadr.argmin()).name == "vehicle" and world.body(1).name == "vehicle"
    assert {"panel", "valve_1", "ee"} <= {world.body(i).name for i in range(world.nbody)} | {
        world.site(i).name for i in range(world.nsite)
    }
    clash = _broken(tmp_path, '<body name="arm_base"', '<body name="valve_1"', "robot.xml")
    with pytest.raises(ConfigError, match=r"simulation\.site: .*does not compile.*valve_1"):
        world_model(load_robot(clash), site_at(""))


# -- no module names the robot's parts ----------------------------------------------------------
# Where the shipped robot's names may still stand, and why (each a later slice's):
# none of the robot's (the key table names the cameras' roles: camera/left, ...); of the site's,
# the default mission's parts (the configuration's defaults are the shipped pair's)
ALLOWED: dict[str, set[str]] = {"config/system.py": {"valve_1", "lever_0"}}
PACKAGE_ROOMS = (
    "common",
    "description",
    "interface",
    "timing",
    "security",
    "config",
    "bus",
    "linkemu",
    "scene",
    "recording",
    "ros2",
    "stations",
    "launch",
    "validation",
    "cli",
    "console",
)


def _names() -> set[str]:
    robot = robot_at("")
    return {
        *robot.arm_joints,
        *robot.gripper_joints,
        *robot.thrusters,
        *robot.cameras,
        robot.end_effector_site,
        *robot.spec.arm.clearance_bodies,
        *site_at("").panel.part_names,
    }


def test_no_module_names_a_joint_thruster_camera_or_site_of_the_robot_or_a_part_of_the_panel() -> None:
    """Each of the shipped robot's names and its site's parts', as a quoted string in the
    package's code (comments and docstrings aside, as prose may mention them), only in its
    package and where ALLOWED says."""
    names = _names()
    quoted = re.compile(r"""["']([A-Za-z_][A-Za-z0-9_]*)["']""")
    found = []
    for room in PACKAGE_ROOMS:
        for path in sorted((ROOT / room).rglob("*.py")):
            relative = path.relative_to(ROOT).as_posix()
            for number, line in enumerate(path.read_text().splitlines(), 1):
                code = line.split("#", 1)[0]
                for name in set(quoted.findall(code)) & names:
                    if name not in ALLOWED.get(relative, set()) and not _in_docstring(path, number):
                        found.append(f"{relative}:{number}: {name!r}")
    assert found == [], "\n".join(found)


def _in_docstring(path: Path, number: int) -> bool:
    import ast

    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):
        is_text = isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant)
        if is_text and isinstance(node.value.value, str) and node.lineno <= number <= (node.end_lineno or 0):
            return True
    return False


def test_the_name_check_finds_a_constant(tmp_path: Path) -> None:
    """The check itself: a module constant with a joint's name is caught."""
    quoted = re.compile(r"""["']([A-Za-z_][A-Za-z0-9_]*)["']""")
    line = 'WRIST = "wrist_pitch"  # the wrist'
    assert set(quoted.findall(line.split("#", 1)[0])) & _names() == {"wrist_pitch"}
