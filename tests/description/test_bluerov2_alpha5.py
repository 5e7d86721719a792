"""The BlueROV2 Heavy with a Reach Alpha 5 (description/models/robots/bluerov2_heavy_alpha5): the package
loads; its thrusters move the vehicle in all six axes; its arm has the published joint ranges, link
lengths, reach and mass; the robot is neutral in the sea; Pinocchio and MuJoCo put the arm's frames
in the same places; the stowed arm is clear of the vehicle and of itself; the stereo pair sees the
arm's work."""

from __future__ import annotations

import itertools
import math

import mujoco
import numpy as np
import pinocchio as pin
import pytest

from abyss.common.geometry import Intrinsics
from abyss.description.robot import COMMANDED_AXES, ROBOTS_DIR, Robot, load_robot, thrust_matrix
from abyss.stations.onboard.arm_control import XYZW, ArmKinematics
from abyss.stations.simulation.marine import WATER_DENSITY_KGPM3, Buoyancy, geom_volume_m3, wet_geoms

PACKAGE = ROBOTS_DIR / "bluerov2_heavy_alpha5"

# Reach Robotics, Reach Alpha 5 datasheet (RA-5001): the joints' ranges (E base rotate 350 deg,
# D shoulder and C elbow 185 deg; zero folded back, as Robotic-Decision-Making-Lab/reach's
# reach_description/description/alpha_5/urdf.xacro has them); B, the wrist rotate, has no stop on
# the device: one turn, 0-6.2 rad, as Reach's own description has it (Reach-Robotics/
# reach_robotics_sdk, ROS2/bpl_alpha_description/urdf/alpha_5.urdf.xacro) [deg], base to tool
PUBLISHED_RANGES_DEG = {
    "axis_e": (0.0, 350.0),
    "axis_d": (0.0, 185.0),
    "axis_c": (0.0, 185.0),
    "axis_b": (0.0, 355.0),
}
# Reach's kinematics sheet, its Denavit-Hartenberg parameters (as Robotic-Decision-Making-Lab/angler
# carries them: angler_description/config/dh.json) [m]
D0_M = 0.0462  # from the arm's base frame to the shoulder (D), along the base rotate's (E) axis
A0_M = 0.020  # the shoulder's axis off E's axis
A1_M = 0.15071  # shoulder to elbow (C), between their parallel axes
A2_M = 0.020  # the elbow's axis off the wrist rotate's (B) axis
D3_M = 0.180  # the tool point along B's axis from the elbow's common normal
# the datasheet: full reach (the arm straight, to the jaws' tips), mass in air
REACH_M = 0.400
ARM_MASS_KG = 1.36
# Reach's Alpha end-effector datasheet: the standard jaws (RA-1014) open 80 mm
JAW_OPENING_M = 0.080
# von Benzon et al. 2022, table 2: the BlueROV2 Heavy's mass and displaced volume
VEHICLE_MASS_KG = 13.5
VEHICLE_VOLUME_M3 = 0.0134


@pytest.fixture(scope="module")
def robot() -> Robot:
    return load_robot(PACKAGE)


@pytest.fixture(scope="module")
def model(robot: Robot) -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_path(str(robot.model_file))


def _posed(model: mujoco.MjModel, robot: Robot, arm_rad: tuple[float, ...]) -> mujoco.MjData:
    """The robot alone, its vehicle at the origin and level, its arm at `arm_rad`; kinematics done."""
    data = mujoco.MjData(model)
    base = model.joint(robot.base).qposadr[0]
    data.qpos[base : base + 7] = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]
    for name, angle_rad in zip(robot.arm_joints, arm_rad, strict=True):
        data.qpos[model.joint(name).qposadr[0]] = angle_rad
    mujoco.mj_kinematics(model, data)
    mujoco.mj_camlight(model, data)
    return data


def _axis(model: mujoco.MjModel, data: mujoco.MjData, joint: str) -> tuple[np.ndarray, np.ndarray]:
    j = model.joint(joint).id
    return data.xanchor[j].copy(), data.xaxis[j].copy()


def _off_line_m(point: np.ndarray, anchor: np.ndarray, axis: np.ndarray) -> float:
    offset = point - anchor
    return float(np.linalg.norm(offset - (offset @ axis) * axis))


def test_the_package_loads_with_its_names(robot: Robot, model: mujoco.MjModel) -> None:
    assert robot.name == "BlueROV2 Heavy with a Reach Alpha 5" and robot.spec.source
    assert robot.arm_joints == ("axis_e", "axis_d", "axis_c", "axis_b")  # base rotate to wrist rotate
    assert robot.gripper_joints == ("finger_left", "finger_right")
    assert robot.spec.arm.gripper.kind == "parallel"
    assert robot.spec.arm.gripper.opening_m == pytest.approx(JAW_OPENING_M)
    assert sum(model.joint(n).range[1] for n in robot.gripper_joints) == pytest.approx(JAW_OPENING_M)
    assert robot.clearance_points == ("arm_link3", "arm_link4", "ee")  # the elbow, the wrist, the tool
    assert len(robot.thrusters) == 8
    assert robot.cameras == ("cam_left", "cam_right", "cam_depth")
    for name in robot.nav_sensor_names:  # each navigation sensor has its place on the vehicle
        assert model.site(name).bodyid[0] == model.body(robot.base).id


def test_the_eight_thrusters_move_the_vehicle_in_all_six_axes(robot: Robot, model: mujoco.MjModel) -> None:
    """Four vectored horizontal T200s and four vertical: the allocation has rank six; the low level
    commands surge, sway, heave and yaw (COMMANDED_AXES), and every one of them is actuated."""
    allocation = thrust_matrix(model, robot.base, robot.thrusters)
    assert allocation.shape == (6, 8)
    assert np.linalg.matrix_rank(allocation) == 6
    vertical = np.isclose(np.abs(allocation[2]), 1.0)
    assert vertical.sum() == 4 and np.allclose(allocation[2, ~vertical], 0.0)  # the others horizontal
    assert robot.actuated_axes == COMMANDED_AXES


def test_the_arm_joints_have_the_published_ranges(robot: Robot, model: mujoco.MjModel) -> None:
    bodies = [model.joint(name).bodyid[0] for name in robot.arm_joints]
    for parent, child in itertools.pairwise(bodies):  # in chain order, base to tool
        assert model.body_parentid[child] == parent
    for name, (lower_deg, upper_deg) in PUBLISHED_RANGES_DEG.items():
        joint = model.joint(name)
        assert joint.type[0] == mujoco.mjtJoint.mjJNT_HINGE and model.jnt_limited[joint.id]
        assert np.degrees(joint.range) == pytest.approx([lower_deg, upper_deg], abs=1e-6), name


def test_the_arm_has_the_published_lengths_and_reach(robot: Robot, model: mujoco.MjModel) -> None:
    """The distances between the joints' axes in a pose of the arm (any: they are the links'),
    and the jaws' tips with the arm straight."""
    data = _posed(model, robot, (2.0, 1.2, 2.1, 0.7))
    (pe, ue), (pd, ud), (pc, uc), (pb, ub) = (_axis(model, data, n) for n in robot.arm_joints)
    base = data.xpos[model.body("arm_base").id]
    assert (pd - base) @ ue == pytest.approx(D0_M, abs=1e-6)
    assert _off_line_m(pd, pe, ue) == pytest.approx(A0_M, abs=1e-6)
    assert abs(ud @ uc) == pytest.approx(1.0) and abs(ue @ ud) == pytest.approx(0.0, abs=1e-9)
    assert _off_line_m(pc, pd, ud) == pytest.approx(A1_M, abs=1e-5)
    assert abs(uc @ ub) == pytest.approx(0.0, abs=1e-9)
    normal = np.cross(uc, ub)
    assert abs((pb - pc) @ normal) / np.linalg.norm(normal) == pytest.approx(A2_M, abs=1e-6)
    tool = data.site_xpos[model.site(robot.end_effector_site).id]
    assert _off_line_m(tool, pb, ub) == pytest.approx(0.0, abs=1e-9)  # on B's axis
    foot = pb + ((pc - pb) @ ub) * ub  # where the elbow's common normal meets B's axis
    assert abs((tool - foot) @ ub) == pytest.approx(D3_M, abs=1e-6)
    straight = _posed(model, robot, (0.5, math.pi, math.pi, 0.0))
    anchor, axis = _axis(model, straight, "axis_e")
    tips = max(
        float((corner - anchor) @ axis)
        for g in range(model.ngeom)
        if model.body(model.geom_bodyid[g]).name in robot.gripper_joints and model.geom_contype[g]
        for corner in _box_corners(model, straight, g)
    )
    assert tips == pytest.approx(REACH_M, abs=0.005)
    shoulder, reach = ArmKinematics(robot).reach()  # base to tool through the joints: no more than it
    assert shoulder == pytest.approx(pe, abs=1e-9) and 0.9 * REACH_M < reach < REACH_M


def _box_corners(model: mujoco.MjModel, data: mujoco.MjData, geom: int) -> list[np.ndarray]:
    half = model.geom_size[geom]
    rotation = data.geom_xmat[geom].reshape(3, 3)
    return [
        data.geom_xpos[geom] + rotation @ (half * np.array(s))
        for s in np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).T.reshape(-1, 3)
    ]


def test_the_arm_has_the_published_mass_and_each_link_is_neutral(robot: Robot, model: mujoco.MjModel) -> None:
    arm = [b for b in range(model.nbody) if model.body_rootid[b] and b >= model.body("arm_base").id]
    assert model.body_mass[arm].sum() == pytest.approx(ARM_MASS_KG, rel=0.005)
    buoyancy = Buoyancy(model, dry=(robot.base,))
    lift_kg = dict(zip(buoyancy.bodies.tolist(), WATER_DENSITY_KGPM3 * buoyancy.volume_m3, strict=True))
    for body in arm:
        assert lift_kg[body] == pytest.approx(model.body_mass[body], rel=1e-3), model.body(body).name


def test_the_robot_is_neutral_in_the_sea(robot: Robot, model: mujoco.MjModel) -> None:
    """The vehicle's published mass and volume, its trim ballast and the arm: the whole robot's
    weight and the water it displaces within 1 % of each other; and the hull's wet parts in the
    MJCF displace the volume robot.toml gives, about the centre it gives."""
    vehicle = robot.marine
    assert vehicle.volume_m3 == VEHICLE_VOLUME_M3
    base = model.body(robot.base).id
    assert model.body_mass[base] == VEHICLE_MASS_KG
    arm_m3 = Buoyancy(model, dry=(robot.base,)).volume_m3.sum()
    lift_kg = WATER_DENSITY_KGPM3 * (vehicle.volume_m3 + arm_m3)
    mass_kg = model.body_mass.sum()
    assert abs(lift_kg - mass_kg) < 0.01 * mass_kg
    hull = [g for g in np.flatnonzero(wet_geoms(model)) if model.geom_bodyid[g] == base]
    volumes = np.array([geom_volume_m3(model.geom_type[g], model.geom_size[g]) for g in hull])
    assert volumes.sum() == pytest.approx(vehicle.volume_m3, rel=1e-3)
    centre = (volumes[:, None] * model.geom_pos[hull]).sum(axis=0) / volumes.sum()
    assert centre == pytest.approx(vehicle.centre_of_buoyancy_m_body, abs=0.002)


def test_pinocchio_and_mujoco_put_the_arm_frames_in_the_same_places(
    robot: Robot, model: mujoco.MjModel
) -> None:
    """The package's MJCF in MuJoCo alone and in Pinocchio (as ArmKinematics reads it): the tool
    point's pose and the clearance bodies' origins, the vehicle anywhere, the arm anywhere in its
    ranges."""
    pinocchio = pin.buildModelFromMJCF(str(robot.model_file))
    frames = pinocchio.createData()
    rng = np.random.default_rng(7)
    data = mujoco.MjData(model)
    joints = [model.joint(n) for n in robot.arm_joints]
    for _ in range(5):
        position = rng.uniform(-5.0, 5.0, 3)
        quat_wxyz = rng.normal(size=4)
        quat_wxyz /= np.linalg.norm(quat_wxyz)
        arm_rad = [rng.uniform(*j.range) for j in joints]
        data.qpos[:3], data.qpos[3:7] = position, quat_wxyz
        for joint, angle_rad in zip(joints, arm_rad, strict=True):
            data.qpos[joint.qposadr[0]] = angle_rad
        mujoco.mj_kinematics(model, data)
        q = pin.neutral(pinocchio)
        q[:3], q[3:7] = position, quat_wxyz[XYZW]
        for name, angle_rad in zip(robot.arm_joints, arm_rad, strict=True):
            q[pinocchio.joints[pinocchio.getJointId(name)].idx_q] = angle_rad
        pin.framesForwardKinematics(pinocchio, frames, q)
        ee = frames.oMf[pinocchio.getFrameId(robot.end_effector_site)]
        site = model.site(robot.end_effector_site).id
        assert ee.translation == pytest.approx(data.site_xpos[site], abs=1e-9)
        assert ee.rotation == pytest.approx(data.site_xmat[site].reshape(3, 3), abs=1e-9)
        for body in robot.spec.arm.clearance_bodies:
            placed = frames.oMf[pinocchio.getFrameId(body)].translation
            assert placed == pytest.approx(data.xpos[model.body(body).id], abs=1e-9)


def test_the_stowed_arm_is_clear_of_the_vehicle_and_of_itself(robot: Robot, model: mujoco.MjModel) -> None:
    data = _posed(model, robot, robot.stowed_rad)
    mujoco.mj_collision(model, data)
    assert data.ncon == 0
    frame = model.geom("frame").id
    arm = [
        g
        for g in range(model.ngeom)
        if model.geom_contype[g] and model.geom_bodyid[g] > model.body("arm_base").id
    ]
    assert min(mujoco.mj_geomDistance(model, data, g, frame, 1.0, None) for g in arm) > 0.015
    margin_rad = 0.05  # onboard's joint_limit_margin_rad: the controller starts inside its constraints
    for name, angle_rad in zip(robot.arm_joints, robot.stowed_rad, strict=True):
        lower, upper = model.joint(name).range
        assert lower + margin_rad < angle_rad < upper - margin_rad, name


def test_the_stereo_pair_sees_the_arm_reaching_ahead(robot: Robot, model: mujoco.MjModel) -> None:
    """A 0.08-0.1 m baseline, the two cameras alike and parallel; the tool point, the arm straight
    out ahead (E turned forward, the upper arm level, the elbow straight), in both images."""
    data = _posed(model, robot, (math.pi, math.pi / 2, math.pi, 0.0))
    left, right = model.camera(robot.stereo_left).id, model.camera(robot.stereo_right).id
    assert 0.08 <= np.linalg.norm(data.cam_xpos[left] - data.cam_xpos[right]) <= 0.10
    assert data.cam_xmat[left] == pytest.approx(data.cam_xmat[right])
    assert model.cam_fovy[left] == model.cam_fovy[right]
    tool = data.site_xpos[model.site(robot.end_effector_site).id]
    assert tool[0] > 0.45  # well ahead of the frame (its bow at 0.23 m)
    for camera in (left, right):
        intrinsics = Intrinsics.from_fovy(640, 480, float(model.cam_fovy[camera]))
        in_camera = data.cam_xmat[camera].reshape(3, 3).T @ (tool - data.cam_xpos[camera])
        assert in_camera[2] < 0  # in front: a MuJoCo camera looks along its -z
        u = intrinsics.cx_px + intrinsics.fx_px * in_camera[0] / -in_camera[2]
        v = intrinsics.cy_px - intrinsics.fy_px * in_camera[1] / -in_camera[2]
        assert 0 < u < intrinsics.width_px and 0 < v < intrinsics.height_px
