"""Robot packages written in URDF (xacro accepted), as ROS users write them: `[model] format =
"urdf"` in robot.toml, whose `[model]` then carries what a URDF cannot say and the simulation
needs, each on one of the URDF's links: the sites (`[[model.sites]]`: the thrusters', the
sensors', the end effector's), the cameras (`[[model.cameras]]`), the wet links (`wet_links`:
their collision geoms displace water; every link's by default) and the arm's servos
(`[model.servos]`: gains, and limits where the URDF's joint limits are not the ones wanted).

`urdf_spec` turns such a package into the MuJoCo spec the rest of the testbed reads, as it reads
an MJCF package's: xacro expands the file (`[model] xacro_args`; `$(find pkg)` and
`package://pkg/...` resolve as description/ros_packages.py says: the robot package itself, or a package
under ABYSS_PACKAGE_PATH), MuJoCo's own URDF compiler reads it (meshes at absolute paths, the
URDF's visuals kept for the cameras, the fixed links fused into the moving ones), and the spec then
gains the free joint of the root link (`[model] base`), the sites, the cameras, a motor per
thruster (`[thrusters]`) and a velocity servo per arm and gripper joint (`[arm]`), as the
shipped MJCF has them. `write_mjcf` writes that model as MJCF for Pinocchio. A link, joint,
package, file or xacro argument that is not there, or a URDF that MuJoCo refuses, is a
ConfigError naming robot.toml (or the URDF) and the field."""

from __future__ import annotations

import hashlib
import math
import os
import tempfile
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from abyss.common.errors import ConfigError
from abyss.description.robot_file import JointServo, ModelSection, RobotFile, ServosSection
from abyss.description.ros_packages import find_package, missing_package, xacro_text

if TYPE_CHECKING:
    import mujoco


WET_CLASS = "wet"  # the shipped MJCF's class of the geoms that displace water
WET_DENSITY_KGPM3 = 1025.0  # sea water: a wet link with no <inertial> of its own floats neutral
SITE_GROUP = 3  # sites are the simulation's, never in a camera's image
HIDDEN_GROUP = 3  # a link's collision geoms where it has visuals: the cameras see the visuals
FORMATS = (".urdf", ".xacro")  # a file's last suffix: plain URDF, or xacro (.urdf.xacro, .xacro)


@dataclass(frozen=True)
class UrdfJoint:
    name: str
    kind: str  # URDF's joint type: revolute, continuous, prismatic, fixed, ...
    parent: str
    child: str
    effort: float | None  # the <limit>'s, None where absent or zero
    velocity: float | None


@dataclass(frozen=True)
class Urdf:
    """What this module reads of a URDF itself (MuJoCo reads the rest): its links and joints."""

    links: tuple[str, ...]
    joints: dict[str, UrdfJoint]

    @property
    def root(self) -> str:
        children = {j.child for j in self.joints.values()}
        roots = [name for name in self.links if name not in children]
        return roots[0] if len(roots) == 1 else ""


# -- the URDF, read and prepared for MuJoCo's compiler ------------------------------------------
def read_urdf(root: ET.Element) -> Urdf:
    """The links and joints of a URDF's <robot>."""

    def limit(joint: ET.Element, key: str) -> float | None:
        """The <limit>'s `key`; None for none, zero or not a number (MuJoCo names that one)."""
        element = joint.find("limit")
        try:
            number = float(element.get(key, "0")) if element is not None else 0.0
        except ValueError:
            return None
        return number if number > 0.0 and math.isfinite(number) else None

    def link(joint: ET.Element, tag: str) -> str:
        element = joint.find(tag)
        return "" if element is None else element.get("link", "")

    joints = {
        j.get("name", ""): UrdfJoint(
            j.get("name", ""),
            j.get("type", ""),
            link(j, "parent"),
            link(j, "child"),
            limit(j, "effort"),
            limit(j, "velocity"),
        )
        for j in root.findall("joint")
    }
    return Urdf(tuple(element.get("name", "") for element in root.findall("link")), joints)


def _resolve_meshes(root: ET.Element, model_file: Path, own: Path, path: Path) -> None:
    """Every mesh's file at its absolute path: package://pkg/ through find_package, file:// and
    relative paths (from the model file's directory) as they are."""
    for mesh in root.iter("mesh"):
        name = mesh.get("filename", "")
        if name.startswith("package://"):
            package, _, rest = name.removeprefix("package://").partition("/")
            found = find_package(package, own)
            if found is None:
                raise ConfigError(
                    "model.file", f"{model_file}: {name}: {missing_package(package, own)}", str(path)
                )
            file = found / rest
        else:
            file = model_file.parent / name.removeprefix("file://")
        if not file.is_file():
            raise ConfigError("model.file", f"{model_file}: mesh {name}: no such file {file}", str(path))
        mesh.set("filename", str(file.resolve()))


def _float_the_base(root: ET.Element, urdf: Urdf, base: str, model_file: Path, path: Path) -> None:
    """MuJoCo's URDF compiler: the fixed links fused, the visuals kept, mesh paths as given; the
    base, the URDF's root link, floats on a free joint of its name under a world link."""
    if base != urdf.root:
        raise ConfigError(
            "model.base", f"{base!r} is not the root link of {model_file} ({urdf.root or 'none'})", str(path)
        )
    extension = root.find("mujoco")
    if extension is None:
        extension = ET.Element("mujoco")
        root.insert(0, extension)
    compiler = extension.find("compiler")
    if compiler is None:
        compiler = ET.SubElement(extension, "compiler")
    compiler.attrib.update(fusestatic="true", discardvisual="false", strippath="false")
    root.insert(1, ET.Element("link", name="world"))  # not the URDF's: its root is the base
    joint = ET.Element("joint", name=base, type="floating")
    ET.SubElement(joint, "parent", link="world")
    ET.SubElement(joint, "child", link=base)
    root.insert(2, joint)


def _parse(text: str, model_file: Path, path: Path) -> ET.Element:
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise ConfigError("model.file", f"{model_file} is not XML: {exc}", str(path)) from None
    if root.tag != "robot":
        raise ConfigError(
            "model.file", f"{model_file}: a URDF's root element is <robot>, not <{root.tag}>", str(path)
        )
    return root


# -- the spec ----------------------------------------------------------------------------------
def urdf_spec(directory: Path, robot: RobotFile, path: Path) -> mujoco.MjSpec:
    """The robot package's URDF as a MuJoCo spec with what robot.toml adds to it (see the
    module's text), its fixed links fused into the moving ones (by MuJoCo's compiler, which
    fuses them in the spec itself: a spec composed into a world is compiled under the world's
    compiler, which fuses nothing); ConfigError naming robot.toml (`path`) and the field for a
    bad one."""
    spec = _composed(directory, robot, path)
    try:
        spec.compile()
    except ValueError as exc:  # MuJoCo's compiler's error
        raise ConfigError(
            "model.file", f"MuJoCo refuses {directory / robot.model.file}: {exc}", str(path)
        ) from None
    return spec


def _composed(directory: Path, robot: RobotFile, path: Path) -> mujoco.MjSpec:
    """The URDF as MuJoCo reads it, with robot.toml's additions, not yet compiled."""
    import mujoco

    model = robot.model
    model_file = directory / model.file
    if not model_file.is_file():
        raise ConfigError("model.file", f"no such file: {model_file}", str(path))
    if model_file.suffix not in FORMATS:
        raise ConfigError("model.file", f"{model_file}: a URDF is *.urdf, *.urdf.xacro or *.xacro", str(path))
    if model_file.suffix == ".xacro":
        text = xacro_text(
            model_file, {k: _xacro_value(v) for k, v in model.xacro_args.items()}, directory, path
        )
    else:
        text = model_file.read_text()
    root = _parse(text, model_file, path)
    urdf = read_urdf(root)
    _check_links(robot, urdf, path)
    _resolve_meshes(root, model_file, directory, path)
    _float_the_base(root, urdf, model.base, model_file, path)
    try:
        spec = mujoco.MjSpec.from_string(ET.tostring(root, encoding="unicode"))
    except ValueError as exc:  # MuJoCo's URDF compiler's error
        raise ConfigError("model.file", f"MuJoCo refuses {model_file}: {exc}", str(path)) from None
    _wet(spec, model.wet_links)
    _sites(spec, robot, path)
    _cameras(spec, robot, path)
    _motors(spec, robot, path)
    _servos(spec, robot, urdf, path)
    return spec


def _xacro_value(value: str | bool | int | float) -> str:
    return str(value).lower() if isinstance(value, bool) else str(value)


def _check_links(robot: RobotFile, urdf: Urdf, path: Path) -> None:
    """Every link robot.toml names is one of the URDF's, every site and camera named once, every
    servo's joint an arm's."""
    model = robot.model
    named = [(f"model.sites[{i}].link", s.link) for i, s in enumerate(model.sites)]
    named += [(f"model.cameras[{i}].link", c.link) for i, c in enumerate(model.cameras)]
    named += [("model.wet_links", link) for link in model.wet_links or ()]
    for where, link in named:
        if link not in urdf.links:
            raise ConfigError(
                where, f"{link!r}: no link of that name in the URDF ({', '.join(urdf.links)})", str(path)
            )
    for where, names in (("model.sites", model.sites), ("model.cameras", model.cameras)):
        given = [n.name for n in names]
        twice = sorted({n for n in given if given.count(n) > 1})
        if twice:
            raise ConfigError(where, f"{', '.join(twice)} named more than once", str(path))
    joints = (*robot.arm.joints, *robot.arm.gripper.joints)
    for name in model.servos.joints:
        if name not in joints:
            raise ConfigError(
                f"model.servos.joints.{name}", f"not one of the arm's joints ({', '.join(joints)})", str(path)
            )


def _wet(spec: mujoco.MjSpec, wet_links: tuple[str, ...] | None) -> None:
    """The wet links' collision geoms in the class "wet" (density 1025, MuJoCo's ellipsoid fluid
    shape on); a link's collision geoms hidden from the cameras where it has visuals."""
    wet = spec.add_default(WET_CLASS, spec.default)
    wet.geom.density = WET_DENSITY_KGPM3
    wet.geom.fluid_ellipsoid = 1.0
    for body in spec.bodies:
        geoms = body.geoms
        visual = [g.contype == 0 and g.conaffinity == 0 for g in geoms]
        for geom, is_visual in zip(geoms, visual, strict=True):
            if is_visual:
                continue
            if any(visual):
                geom.group = HIDDEN_GROUP
            if wet_links is None or body.name in wet_links:
                geom.classname = wet
                geom.density = WET_DENSITY_KGPM3
                geom.fluid_ellipsoid = 1.0


def _sites(spec: mujoco.MjSpec, robot: RobotFile, path: Path) -> None:
    for i, site in enumerate(robot.model.sites):
        if site.zaxis is not None and site.xyaxes is not None:
            raise ConfigError(f"model.sites[{i}]", "give zaxis or xyaxes, not both", str(path))
        where = f"model.sites[{i}].{'zaxis' if site.zaxis is not None else 'xyaxes'}"
        quat = _quat(site.zaxis, site.xyaxes, where, path)
        spec.body(site.link).add_site(
            name=site.name,
            pos=list(site.position_m),
            quat=list(quat),
            size=[site.size_m] * 3,
            group=SITE_GROUP,
        )


def _cameras(spec: mujoco.MjSpec, robot: RobotFile, path: Path) -> None:
    for i, camera in enumerate(robot.model.cameras):
        if not 0.0 < camera.fovy_deg < 180.0:
            raise ConfigError(
                f"model.cameras[{i}].fovy_deg", f"{camera.fovy_deg}: needs (0, 180) degrees", str(path)
            )
        quat = _quat(None, camera.xyaxes, f"model.cameras[{i}].xyaxes", path)
        spec.body(camera.link).add_camera(
            name=camera.name, pos=list(camera.position_m), quat=list(quat), fovy=camera.fovy_deg
        )


def _quat(
    zaxis: tuple[float, ...] | None, xyaxes: tuple[float, ...] | None, where: str, path: Path
) -> np.ndarray:
    """(w, x, y, z) of a frame given as MJCF gives one: its z axis (the shortest turn from the
    parent's z onto it), or its x and y axes (y made orthogonal to x); identity for neither."""
    import mujoco

    quat = np.array([1.0, 0.0, 0.0, 0.0])
    if zaxis is not None:
        if np.linalg.norm(zaxis) < 1e-9:
            raise ConfigError(where, "needs a non-zero axis", str(path))
        mujoco.mju_quatZ2Vec(quat, np.asarray(zaxis, dtype=float))
    elif xyaxes is not None:
        x, y = np.asarray(xyaxes[:3], dtype=float), np.asarray(xyaxes[3:], dtype=float)
        y = y - x * (x @ y) / max(x @ x, 1e-18)
        if np.linalg.norm(x) < 1e-9 or np.linalg.norm(y) < 1e-9:
            raise ConfigError(where, "needs two non-zero axes, not parallel", str(path))
        x, y = x / np.linalg.norm(x), y / np.linalg.norm(y)
        mujoco.mju_mat2Quat(quat, np.column_stack([x, y, np.cross(x, y)]).ravel())
    return quat


def _motors(spec: mujoco.MjSpec, robot: RobotFile, path: Path) -> None:
    """A motor per thruster on the site of its name, pushing along the site's z."""
    import mujoco

    sites = {s.name for s in robot.model.sites}
    limit_n = robot.thrusters.forward_max_n
    for name in robot.thrusters.names:
        if name not in sites:
            raise ConfigError(
                "thrusters.names", f"{name}: no site of that name in [[model.sites]]", str(path)
            )
        motor = spec.add_actuator(name=name, target=name, trntype=mujoco.mjtTrn.mjTRN_SITE)
        motor.set_to_motor()
        motor.gear = [0.0, 0.0, 1.0, 0.0, 0.0, 0.0]
        motor.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
        motor.ctrlrange = [-limit_n, limit_n]


def _servos(spec: mujoco.MjSpec, robot: RobotFile, urdf: Urdf, path: Path) -> None:
    """A velocity servo per arm and gripper joint of the URDF, named as the joint (a joint it
    lacks is load_robot's to name)."""
    import mujoco

    servos = robot.model.servos
    arm = [(j, servos.arm_kv, servos.arm_armature) for j in robot.arm.joints]
    gripper = [(j, servos.gripper_kv, servos.gripper_armature) for j in robot.arm.gripper.joints]
    for name, kv, armature in arm + gripper:
        joint = urdf.joints.get(name)
        if joint is None:
            continue
        own = servos.joints.get(name, JointServo())
        force = _limit(own.force_max, joint.effort, name, "force_max", "effort", path)
        speed = _limit(own.speed_max, joint.velocity, name, "speed_max", "velocity", path)
        servo = spec.add_actuator(name=name, target=name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        servo.set_to_velocity(kv=kv if own.kv is None else own.kv)
        servo.ctrllimited = servo.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
        servo.ctrlrange, servo.forcerange = [-speed, speed], [-force, force]
        if armature > 0.0:
            spec.joint(name).armature = armature


def _limit(own: float | None, urdf: float | None, joint: str, key: str, attribute: str, path: Path) -> float:
    value = urdf if own is None else own
    if value is None or not value > 0.0 or not math.isfinite(value):
        raise ConfigError(
            f"model.servos.joints.{joint}.{key}",
            f"the URDF gives joint {joint} no {attribute} limit: give a positive {key}",
            str(path),
        )
    return value


# -- the MJCF Pinocchio reads --------------------------------------------------------------------
def cache_dir() -> Path:
    """Where the MJCF written for Pinocchio goes: $XDG_CACHE_HOME (or ~/.cache)/abyss/robots."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "abyss" / "robots"


def write_mjcf(directory: Path, robot: RobotFile, path: Path) -> Path:
    """The package's model (urdf_spec's) as MJCF in the cache (a directory per content, so that
    every reader of one version reads the same file, written whole), its fixed links as bodies of
    their own: Pinocchio's MJCF reader takes no <frame>, where MuJoCo writes a fused link's
    contents, and a fixed body is a fixed frame to it."""
    spec = _composed(directory, robot, path)
    spec.compiler.fusestatic = False
    spec.compile()
    xml = spec.to_xml()
    target = cache_dir() / hashlib.sha256(xml.encode()).hexdigest()[:16] / "robot.xml"
    if not target.is_file():
        target.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile("w", dir=target.parent, suffix=".tmp", delete=False) as out:
            out.write(xml)
        os.replace(out.name, target)
    return target


def refuse_in_mjcf(model: ModelSection, path: Path) -> None:
    """An MJCF package carries its own sites, cameras, wet geoms and actuators: robot.toml's
    URDF-only fields are refused there, naming the first given."""
    given = {
        "xacro_args": bool(model.xacro_args),
        "wet_links": model.wet_links is not None,
        "sites": bool(model.sites),
        "cameras": bool(model.cameras),
        "servos": model.servos != ServosSection(),
    }
    for key, is_given in given.items():
        if is_given:
            raise ConfigError(
                f"model.{key}", 'a URDF package\'s (format = "urdf"): an MJCF carries its own', str(path)
            )
