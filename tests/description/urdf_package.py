"""A robot package written as ROS users write one, in URDF with xacro, for the tests (and for a
whole-system test to fly): a small ROV ("minirov", a BlueROV2-sized hull) with six thrusters
(four vectored horizontal ones and two vertical ones: surge, sway, heave and yaw), a five-joint
arm under its bow and a two-finger gripper whose macro comes from a second ROS package
("claw_kit") found through ABYSS_PACKAGE_PATH. Every name differs from the shipped robot's.

`write_urdf_package(root)` writes both packages under `root` and returns where they are;
ABYSS_PACKAGE_PATH must name `package_path` wherever the robot is loaded (description/ros_packages.py).

The vehicle floats neutral: the hull link's mass is that of the water its collision boxes
displace (xacro computes it from the same numbers), the sensor pod fused onto it has no
<inertial> of its own (its wet geom's density, 1025, makes it neutral), and robot.toml's
[buoyancy] volume is the sum of those boxes, its centre their centroid. The arm's links are
neutral on their own (their <inertial> from their volume, by xacro). The marine coefficients are
the shipped work-class ROV's scaled to this hull (see robot.toml's comments)."""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

RHO_KGPM3 = 1025.0
PACKAGE = "minirov_description"
KIT = "claw_kit"
# the hull's wet boxes (the collision geoms of the hull and of the pod fused onto it):
# (centre [m], size [m]) in the hull's frame (x forward, y left, z up)
HULL_BOXES = (((0.0, 0.0, 0.0), (0.5, 0.36, 0.22)), ((0.0, 0.0, 0.15), (0.44, 0.34, 0.08)))
POD_BOX = ((-0.15, 0.0, -0.135), (0.12, 0.1, 0.05))
COG_BELOW_M = 0.04  # the hull's centre of gravity under its boxes' centroid
BOOM_M, STICK_M = 0.22, 0.18  # the xacro arguments robot.toml gives (the boom's default differs)
# the shipped work-class ROV's marine model (its robot.toml), scaled below by its length ratio
WORKCLASS_VOLUME_M3 = 2.916
WORKCLASS_ADDED_MASS = (1004.0, 1788.0, 1788.0, 241.0, 483.0, 483.0)
WORKCLASS_LINEAR = (86.6, 119.9, 119.9, 930.0, 1170.0, 1170.0)
WORKCLASS_QUADRATIC = (866.0, 1199.0, 1199.0, 165.0, 437.0, 437.0)


@dataclass(frozen=True)
class UrdfPackage:
    directory: Path  # the robot package (robot.toml, urdf/, meshes/)
    package_path: str  # ABYSS_PACKAGE_PATH's value: the directory holding claw_kit
    arm_joints: tuple[str, ...] = ("j1", "j2", "j3", "j4", "j5")
    gripper_joints: tuple[str, ...] = ("grip_a", "grip_b")
    thrusters: tuple[str, ...] = ("prop_a", "prop_b", "prop_c", "prop_d", "prop_e", "prop_f")
    cameras: tuple[str, ...] = ("eye_l", "eye_r", "eye_range")
    end_effector_site: str = "grip_point"
    base: str = "hull"


def write_urdf_package(root: Path) -> UrdfPackage:
    """The minirov package under `root`/minirov_description, its gripper's package under
    `root`/ros_ws/claw_kit."""
    directory, kit = root / PACKAGE, root / "ros_ws" / KIT
    for folder in (directory / "urdf", directory / "meshes", kit / "urdf", kit / "meshes"):
        folder.mkdir(parents=True, exist_ok=True)
    (directory / "package.xml").write_text(_manifest(PACKAGE))
    (kit / "package.xml").write_text(_manifest(KIT))
    write_stl_box(directory / "meshes" / "hull.stl", HULL_BOXES[0][1])
    write_stl_box(kit / "meshes" / "palm.stl", (0.04, 0.08, 0.03))
    (kit / "urdf" / "claw.xacro").write_text(CLAW_XACRO)
    (directory / "urdf" / "minirov.urdf.xacro").write_text(robot_xacro())
    (directory / "robot.toml").write_text(robot_toml())
    return UrdfPackage(directory, str(root / "ros_ws"))


def write_stl_box(path: Path, size_m: tuple[float, float, float]) -> None:
    """A binary STL of a box of `size_m` [m] about its centre, its faces outward."""
    half = np.asarray(size_m) / 2
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * half
    faces = ((0, 1, 3), (0, 3, 2), (4, 6, 7), (4, 7, 5), (0, 4, 5), (0, 5, 1))
    faces += ((2, 3, 7), (2, 7, 6), (0, 2, 6), (0, 6, 4), (1, 5, 7), (1, 7, 3))
    with path.open("wb") as out:
        out.write(b"\0" * 80 + struct.pack("<I", len(faces)))
        for face in faces:
            a, b, c = corners[list(face)]
            normal = np.cross(b - a, c - a)
            out.write(struct.pack("<3f", *normal / np.linalg.norm(normal)))
            for corner in (a, b, c):
                out.write(struct.pack("<3f", *corner))
            out.write(b"\0\0")


def _manifest(name: str) -> str:
    return (
        f'<?xml version="1.0"?>\n<package format="3"><name>{name}</name><version>0.1.0</version></package>\n'
    )


def buoyancy() -> tuple[float, tuple[float, float, float]]:
    """The vehicle's displaced volume [m^3] and its centroid [m, hull frame]: its wet boxes'."""
    boxes = (*HULL_BOXES, POD_BOX)
    volumes = np.array([math.prod(size) for _, size in boxes])
    centre = volumes @ np.array([c for c, _ in boxes]) / volumes.sum()
    return float(volumes.sum()), (float(centre[0]), float(centre[1]), float(centre[2]))


def _hull_inertial() -> str:
    """The hull link's <inertial>: the water its two boxes displace, as xacro computes it, its
    centre of gravity COG_BELOW_M under their centroid."""
    (c0, s0), (c1, s1) = HULL_BOXES
    v0, v1 = math.prod(s0), math.prod(s1)
    z = (v0 * c0[2] + v1 * c1[2]) / (v0 + v1) - COG_BELOW_M
    mass = f"${{rho * ({s0[0]}*{s0[1]}*{s0[2]} + {s1[0]}*{s1[1]}*{s1[2]})}}"
    return (
        f'<inertial><origin xyz="0 0 {z:.6f}"/><mass value="{mass}"/>'
        '<inertia ixx="0.97" ixy="0" ixz="0" iyy="1.5" iyz="0" izz="1.67"/></inertial>'
    )


def robot_xacro() -> str:
    (c0, s0), (c1, s1) = HULL_BOXES
    (cp, sp) = POD_BOX
    xyz = lambda v: " ".join(map(str, v))  # noqa: E731
    return f"""<?xml version="1.0"?>
<robot name="minirov" xmlns:xacro="http://www.ros.org/wiki/xacro">
  <xacro:arg name="boom_length_m" default="0.3"/>
  <xacro:property name="rho" value="{RHO_KGPM3}"/>
  <xacro:property name="boom" value="$(arg boom_length_m)"/>
  <xacro:property name="stick" value="$(arg stick_length_m)"/>
  <xacro:include filename="$(find {KIT})/urdf/claw.xacro"/>

  <!-- a thruster: its link's x along its thrust (robot.toml puts the site's z there) -->
  <xacro:macro name="thruster" params="name x y yaw pitch">
    <link name="${{name}}_link">
      <visual><origin rpy="0 ${{pi/2}} 0"/><geometry><cylinder radius="0.045" length="0.07"/></geometry>
        <material name="black"><color rgba="0.1 0.1 0.1 1"/></material></visual>
    </link>
    <joint name="${{name}}_mount" type="fixed">
      <parent link="hull"/><child link="${{name}}_link"/>
        <origin xyz="${{x}} ${{y}} 0" rpy="0 ${{pitch}} ${{yaw}}"/>
    </joint>
  </xacro:macro>

  <!-- an arm link: a cylinder of radius r and length l along the link's x, neutral in sea water -->
  <xacro:macro name="arm_link" params="name r l">
    <link name="${{name}}">
      <inertial><origin xyz="${{l/2}} 0 0" rpy="0 ${{pi/2}} 0"/><mass value="${{rho*pi*r*r*l}}"/>
        <inertia ixx="${{rho*pi*r*r*l*(3*r*r+l*l)/12}}" ixy="0" ixz="0" iyy="${{rho*pi*r*r*l*(3*r*r+l*l)/12}}"
                 iyz="0" izz="${{rho*pi*r*r*l*r*r/2}}"/></inertial>
      <visual><origin xyz="${{l/2}} 0 0" rpy="0 ${{pi/2}} 0"/><geometry>
        <cylinder radius="${{r}}" length="${{l}}"/></geometry></visual>
      <collision><origin xyz="${{l/2}} 0 0" rpy="0 ${{pi/2}} 0"/><geometry>
        <cylinder radius="${{r}}" length="${{l}}"/></geometry></collision>
    </link>
  </xacro:macro>

  <link name="hull">
    {_hull_inertial()}
    <visual><geometry><mesh filename="package://{PACKAGE}/meshes/hull.stl"/></geometry>
      <material name="orange"><color rgba="0.95 0.55 0.1 1"/></material></visual>
    <collision><origin xyz="{xyz(c0)}"/><geometry><box size="{xyz(s0)}"/></geometry></collision>
    <collision><origin xyz="{xyz(c1)}"/><geometry><box size="{xyz(s1)}"/></geometry></collision>
  </link>
  <!-- the DVL's pod under the stern (its sonar and sensors' sites are robot.toml's) -->
  <link name="pod"><collision><geometry><box size="{xyz(sp)}"/></geometry></collision></link>
  <joint name="pod_mount" type="fixed"><parent link="hull"/><child link="pod"/><origin xyz="{xyz(cp)}"/>
    </joint>
  <!-- the camera bar across the bow -->
  <link name="eye_bar"><visual><geometry><box size="0.03 0.16 0.03"/></geometry></visual></link>
  <joint name="eye_bar_mount" type="fixed"><parent link="hull"/><child link="eye_bar"/>
    <origin xyz="0.265 0 0.03"/></joint>

  <xacro:thruster name="prop_a" x="0.2" y="0.2" yaw="${{-pi/4}}" pitch="0"/>
  <xacro:thruster name="prop_b" x="0.2" y="-0.2" yaw="${{pi/4}}" pitch="0"/>
  <xacro:thruster name="prop_c" x="-0.2" y="0.2" yaw="${{pi/4}}" pitch="0"/>
  <xacro:thruster name="prop_d" x="-0.2" y="-0.2" yaw="${{-pi/4}}" pitch="0"/>
  <xacro:thruster name="prop_e" x="0" y="0.21" yaw="0" pitch="${{-pi/2}}"/>
  <xacro:thruster name="prop_f" x="0" y="-0.21" yaw="0" pitch="${{-pi/2}}"/>

  <!-- the arm: under the bow, yaw, two pitches, roll, pitch; then the claw kit's gripper -->
  <link name="arm_mount"><visual><geometry><cylinder radius="0.04" length="0.02"/></geometry></visual></link>
  <joint name="arm_mount_fix" type="fixed"><parent link="hull"/><child link="arm_mount"/>
    <origin xyz="0.18 0 -0.13"/></joint>
  <link name="turret">
    <visual><origin xyz="0 0 -0.03"/><geometry><cylinder radius="0.035" length="0.06"/></geometry></visual>
    <collision><origin xyz="0 0 -0.03"/><geometry><cylinder radius="0.035" length="0.06"/></geometry>
      </collision>
  </link>
  <joint name="j1" type="revolute"><parent link="arm_mount"/><child link="turret"/><origin xyz="0 0 -0.015"/>
    <axis xyz="0 0 1"/><limit lower="-2.6" upper="2.6" effort="40" velocity="1.0"/>
      <dynamics damping="2"/></joint>
  <xacro:arm_link name="boom" r="0.025" l="${{boom}}"/>
  <joint name="j2" type="revolute"><parent link="turret"/><child link="boom"/><origin xyz="0 0 -0.06"/>
    <axis xyz="0 1 0"/><limit lower="-0.4" upper="1.9" effort="40" velocity="1.0"/>
      <dynamics damping="2"/></joint>
  <xacro:arm_link name="stick" r="0.022" l="${{stick}}"/>
  <joint name="j3" type="revolute"><parent link="boom"/><child link="stick"/><origin xyz="${{boom}} 0 0"/>
    <axis xyz="0 1 0"/><limit lower="-2.7" upper="2.7" effort="30" velocity="1.0"/>
      <dynamics damping="2"/></joint>
  <xacro:arm_link name="wrist" r="0.02" l="0.05"/>
  <joint name="j4" type="revolute"><parent link="stick"/><child link="wrist"/><origin xyz="${{stick}} 0 0"/>
    <axis xyz="1 0 0"/><limit lower="-3.0" upper="3.0" effort="10" velocity="1.5"/>
      <dynamics damping="1"/></joint>
  <xacro:arm_link name="hand" r="0.02" l="0.05"/>
  <joint name="j5" type="revolute"><parent link="wrist"/><child link="hand"/><origin xyz="0.05 0 0"/>
    <axis xyz="0 1 0"/><limit lower="-1.8" upper="1.8" effort="10" velocity="1.5"/>
      <dynamics damping="1"/></joint>
  <xacro:claw parent="hand" x="0.05"/>
</robot>
"""


CLAW_XACRO = f"""<?xml version="1.0"?>
<!-- a two-finger parallel claw: a palm fixed to `parent` at x, two fingers sliding apart along y -->
<robot xmlns:xacro="http://www.ros.org/wiki/xacro">
  <xacro:macro name="finger" params="name side">
    <link name="claw_${{name}}">
      <collision><origin xyz="0.03 ${{side*0.006}} 0"/><geometry><box size="0.06 0.012 0.03"/>
        </geometry></collision>
    </link>
    <joint name="grip_${{name}}" type="prismatic"><parent link="palm"/><child link="claw_${{name}}"/>
      <origin xyz="0.02 ${{side*0.012}} 0"/><axis xyz="0 ${{side}} 0"/>
      <limit lower="0" upper="0.02" effort="20" velocity="0.05"/><dynamics damping="5"/></joint>
  </xacro:macro>
  <xacro:macro name="claw" params="parent x">
    <link name="palm">
      <visual><geometry><mesh filename="package://{KIT}/meshes/palm.stl"/></geometry></visual>
      <collision><geometry><box size="0.04 0.08 0.03"/></geometry></collision>
    </link>
    <joint name="palm_fix" type="fixed"><parent link="${{parent}}"/><child link="palm"/>
      <origin xyz="${{x}} 0 0"/></joint>
    <xacro:finger name="a" side="1"/>
    <xacro:finger name="b" side="-1"/>
  </xacro:macro>
</robot>
"""


def _scaled(values: tuple[float, ...], powers: tuple[float, ...], scale: float) -> str:
    return ", ".join(f"{v * scale**p:.4g}" for v, p in zip(values, powers, strict=True))


def robot_toml() -> str:
    volume_m3, centre = buoyancy()
    s = (volume_m3 / WORKCLASS_VOLUME_M3) ** (1 / 3)
    down = f"{math.sin(math.radians(40)):.4f}, 0.0, {math.cos(math.radians(40)):.4f}"
    eyes = f"xyaxes = [0.0, -1.0, 0.0, {down}]"
    thrusters = "\n".join(
        f'[[model.sites]]\nname = "{n}"\nlink = "{n}_link"\nzaxis = [1.0, 0.0, 0.0]  # along the link\'s x\n'
        for n in UrdfPackage(Path(), "").thrusters
    )
    return f"""# minirov: a small ROV in URDF (xacro), as ROS users write (tests/description/urdf_package.py)
name = "minirov"
source = "the tests' URDF package; its marine model the work-class ROV's scaled by the length ratio {s:.4f}"

[model]
file = "urdf/minirov.urdf.xacro"
format = "urdf"
base = "hull"  # the URDF's root link: it floats on a free joint of its name
xacro_args = {{ boom_length_m = {BOOM_M}, stick_length_m = "{STICK_M}" }}

{thrusters}
[[model.sites]]
name = "grip_point"  # the end effector: between the fingers' tips
link = "palm"
position_m = [0.08, 0.0, 0.0]

[[model.sites]]
name = "fls"  # the sonar ([sonar] below), forward-looking: x along the middle beam, 10 degrees down
link = "hull"
position_m = [0.26, 0.0, 0.12]
xyaxes = [0.985, 0.0, -0.174, 0.0, 1.0, 0.0]

[[model.sites]]
name = "beacon"  # the USBL's transponder
link = "hull"
position_m = [-0.1, 0.0, 0.19]

[[model.sites]]
name = "doppler"  # the DVL, looking down
link = "pod"
position_m = [0.0, 0.0, -0.025]
zaxis = [0.0, 0.0, -1.0]

[[model.sites]]
name = "ahrs"
link = "hull"

[[model.sites]]
name = "baro"
link = "hull"
position_m = [-0.25, 0.1, 0.0]

# the stereo pair (0.1 m baseline) and the range camera under the left one, looking forward
# and 40 degrees down, at the arm's work area in front of the bow
[[model.cameras]]
name = "eye_l"
link = "eye_bar"
position_m = [0.02, 0.05, 0.0]
{eyes}
fovy_deg = 70.0

[[model.cameras]]
name = "eye_r"
link = "eye_bar"
position_m = [0.02, -0.05, 0.0]
{eyes}
fovy_deg = 70.0

[[model.cameras]]
name = "eye_range"
link = "eye_bar"
position_m = [0.02, 0.05, -0.03]
{eyes}
fovy_deg = 70.0

[model.servos]  # the simulation's default gains; the gears' reflected inertia keeps them stable
arm_kv = 400.0
gripper_kv = 1000.0
arm_armature = 0.2
gripper_armature = 0.5

[model.servos.joints.j1]
force_max = 30.0  # below the URDF's effort limit (40 N m)

[arm]
joints = ["j1", "j2", "j3", "j4", "j5"]
end_effector_site = "grip_point"
stowed_rad = [0.0, 1.2, -2.1, 0.0, 0.9]  # folded under the bow, the claw ahead of the cameras
clearance_bodies = ["stick", "hand"]

[arm.gripper]
kind = "parallel"
joints = ["grip_a", "grip_b"]
opening_m = 0.04

[cameras]
names = ["eye_l", "eye_r", "eye_range"]
stereo = ["eye_l", "eye_r"]
depth = "eye_range"

[sonar]
site = "fls"

[nav_sensors]
usbl = "beacon"
depth = "baro"
dvl = "doppler"
imu = "ahrs"

[added_mass]
# the work-class ROV's, times s^3 in translation and s^5 in rotation (s: the length ratio)
diagonal = [{_scaled(WORKCLASS_ADDED_MASS, (3, 3, 3, 5, 5, 5), s)}]

[damping]
# linear: s^2 in translation (a drag area at a fixed speed), s^4.5 in rotation (2 zeta sqrt(K I));
# quadratic: s^2 in translation, s^5 in rotation
linear = [{_scaled(WORKCLASS_LINEAR, (2, 2, 2, 4.5, 4.5, 4.5), s)}]
quadratic = [{_scaled(WORKCLASS_QUADRATIC, (2, 2, 2, 5, 5, 5), s)}]

[buoyancy]
# the hull's and the pod's collision boxes; the hull link's mass is the water they displace
volume_m3 = {volume_m3:.8f}
centre_m_body = [{centre[0]:.8f}, {centre[1]:.8f}, {centre[2]:.8f}]

[thrusters]
# T200-like: Blue Robotics' thrusters at 16 V
names = ["prop_a", "prop_b", "prop_c", "prop_d", "prop_e", "prop_f"]
time_constant_s = 0.1
deadband = 0.0625
forward_max_n = 50.0
reverse_max_n = 40.0
"""
