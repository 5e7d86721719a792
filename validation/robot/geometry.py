"""The geometry `abyss robot check` holds a robot package to (validation/robot/check.py): that MuJoCo
and Pinocchio read the same arm from its MJCF, the largest wrench its thrusters give along each
axis, and how much of the arm's reach ahead of the vehicle its stereo pair sees."""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import mujoco
import numpy as np
import pinocchio as pin

from abyss.common.geometry import Intrinsics
from abyss.description.robot import Robot, robot_mjcf, robot_spec

BASE_SPREAD_M = 10.0  # the vehicle placed anywhere within this of the origin, turned any way


@dataclass(frozen=True)
class FrameAgreement:
    """The largest disagreement between MuJoCo and Pinocchio over the arm's frames: the joints'
    origins and axes and the end-effector site's pose, world frame."""

    distance_m: float
    angle_rad: float
    configurations: int
    frames: int  # per configuration
    worst: str  # the frame of the largest distance


def _arm_limits_rad(model: mujoco.MjModel, names: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    """The joints' ranges [rad or m]; an unlimited one's [-pi, pi]."""
    joints = [model.joint(n) for n in names]
    lower = np.array([j.range[0] if model.jnt_limited[j.id] else -math.pi for j in joints])
    upper = np.array([j.range[1] if model.jnt_limited[j.id] else math.pi for j in joints])
    return lower, upper


def _angle_between(a: np.ndarray, b: np.ndarray) -> float:
    return math.atan2(float(np.linalg.norm(np.cross(a, b))), float(a @ b))


def _rotation_angle(a: np.ndarray, b: np.ndarray) -> float:
    """The angle of the rotation between two orientations (3 x 3) [rad], well conditioned near 0."""
    r = a.T @ b
    sine = 0.5 * np.linalg.norm([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    return math.atan2(float(sine), 0.5 * (float(np.trace(r)) - 1.0))


def frame_agreement(robot: Robot, rng: np.random.Generator, configurations: int = 8) -> FrameAgreement:
    """MuJoCo and Pinocchio (`pin.buildModelFromMJCF`, as the onboard computer's ArmKinematics) at
    `configurations` seeded random poses: the arm within its limits, the vehicle anywhere."""
    model = robot_spec(robot).compile()
    data = mujoco.MjData(model)
    kin = pin.buildModelFromMJCF(str(robot_mjcf(robot)))
    kin_data = kin.createData()
    lower, upper = _arm_limits_rad(model, robot.arm_joints)
    mj_joints = [model.joint(n) for n in robot.arm_joints]
    pin_joints = [kin.joints[kin.getJointId(n)] for n in robot.arm_joints]
    base_q = kin.joints[kin.getJointId(robot.base)].idx_q
    base_qpos = int(model.joint(robot.base).qposadr[0])
    gaps: list[tuple[float, float, str]] = []  # (distance [m], angle [rad], frame)
    for _ in range(configurations):
        angles = rng.uniform(lower, upper)
        position = rng.uniform(-BASE_SPREAD_M, BASE_SPREAD_M, 3)
        quat_wxyz = rng.normal(size=4)
        quat_wxyz /= np.linalg.norm(quat_wxyz)
        mujoco.mj_resetData(model, data)
        data.qpos[base_qpos : base_qpos + 7] = (*position, *quat_wxyz)
        q = pin.neutral(kin)
        q[base_q : base_q + 7] = (*position, *quat_wxyz[[1, 2, 3, 0]])
        for joint, pin_joint, angle in zip(mj_joints, pin_joints, angles, strict=True):
            data.qpos[joint.qposadr[0]] = angle
            q[pin_joint.idx_q] = angle
        mujoco.mj_kinematics(model, data)
        pin.computeJointJacobians(kin, kin_data, q)
        pin.updateFramePlacements(kin, kin_data)
        gaps += _gaps(robot, model, data, kin, kin_data)
    far = max(gaps)
    return FrameAgreement(far[0], max(g[1] for g in gaps), configurations, len(robot.arm_joints) + 1, far[2])


def _gaps(
    robot: Robot, model: mujoco.MjModel, data: mujoco.MjData, kin: pin.Model, kin_data: pin.Data
) -> list[tuple[float, float, str]]:
    """Per arm joint (its origin, its axis) and for the end effector (its pose): the distance
    [m] and angle [rad] between MuJoCo's and Pinocchio's, as of their last kinematics."""
    gaps = []
    for name in robot.arm_joints:
        joint, index = model.joint(name).id, kin.getJointId(name)
        jacobian = pin.getJointJacobian(kin, kin_data, index, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        axis = jacobian[3:, kin.joints[index].idx_v]
        distance = float(np.linalg.norm(data.xanchor[joint] - kin_data.oMi[index].translation))
        gaps.append((distance, _angle_between(data.xaxis[joint], axis), name))
    site = model.site(robot.end_effector_site).id
    pose = kin_data.oMf[kin.getFrameId(robot.end_effector_site)]
    distance = float(np.linalg.norm(data.site_xpos[site] - pose.translation))
    angle = _rotation_angle(data.site_xmat[site].reshape(3, 3), pose.rotation)
    return [*gaps, (distance, angle, robot.end_effector_site)]


@dataclass(frozen=True)
class AxisLimit:
    """The largest wrench along one axis and direction with the other actuated axes held at
    zero, and the thrusts that give it."""

    axis: int  # the wrench's row (fx, fy, fz, mx, my, mz)
    sign: int  # +1, -1
    wrench: float  # signed [N or N m]
    thrust_n: np.ndarray  # (n,)


def axis_limits(
    allocation: np.ndarray, actuated: tuple[int, ...], forward_max_n: float, reverse_max_n: float
) -> list[AxisLimit]:
    """Each actuated axis, both ways: the linear program max +-w_i subject to the other actuated
    rows of the allocation (6 x n) at zero and -reverse_max <= t <= forward_max, solved exactly by
    its vertices (`largest_along`). Roll and pitch are left free, as the allocation leaves them."""
    n = allocation.shape[1]
    lower, upper = np.full(n, -reverse_max_n), np.full(n, forward_max_n)
    limits = []
    for axis in actuated:
        held = allocation[[a for a in actuated if a != axis]]
        for sign in (1, -1):
            thrust = largest_along(sign * allocation[axis], held, lower, upper)
            limits.append(AxisLimit(axis, sign, float(allocation[axis] @ thrust), thrust))
    return limits


def largest_along(
    objective: np.ndarray, held: np.ndarray, lower: np.ndarray, upper: np.ndarray
) -> np.ndarray:
    """argmax objective @ t subject to held @ t = 0 and lower <= t <= upper. A vertex of that
    polytope (it has one: t = 0 is feasible, the box bounded) has the held rows' count of thrusts
    free (a basis, its columns independent) and every other at a bound; there are few enough
    (6 thrusters, 3 held rows: 160) to try them all. Of the optimal vertices, their mean: still
    optimal (the optimal face is convex), and symmetric where the layout is, rather than one
    vertex's arbitrary split (the vertical thrusters pushing against each other in surge, a roll
    moment that moves nothing the allocation holds)."""
    n, m = len(objective), held.shape[0]
    vertices = [np.zeros(n)]
    for free in itertools.combinations(range(n), m):
        basis = held[:, free]
        if m and abs(np.linalg.det(basis)) < 1e-9:
            continue
        rest = [j for j in range(n) if j not in free]
        for at_upper in itertools.product((False, True), repeat=n - m):
            thrust = np.zeros(n)
            thrust[rest] = np.where(at_upper, upper[rest], lower[rest])
            if m:
                thrust[list(free)] = np.linalg.solve(basis, -held[:, rest] @ thrust[rest])
            if np.all(thrust >= lower - 1e-9) and np.all(thrust <= upper + 1e-9):
                vertices.append(thrust)
    table = np.array(vertices)
    values = table @ objective
    optimal = table[values >= values.max() - 1e-9 * max(1.0, float(values.max()))]
    return np.asarray(np.unique(optimal.round(9), axis=0).mean(axis=0))


@dataclass(frozen=True)
class Workspace:
    """The arm's tool points at random configurations and what the stereo pair sees of them,
    vehicle frame (at the origin, level): points (k, 3) [m]; `ahead`: in front of the vehicle,
    beyond its stereo pair and within its hull's outline across (y, z), where it meets what it
    works on; `seen`: inside both cameras' images; the hull's outline (its box: lowest, highest
    corner (2, 3)) [m], the cameras' centres (2, 3) [m] and the corners of their images 1 m along
    their axes (2, 4, 3) [m]."""

    points_m_body: np.ndarray
    ahead: np.ndarray
    seen: np.ndarray
    outline_m_body: np.ndarray
    cameras_m_body: np.ndarray
    corners_m_body: np.ndarray

    @property
    def share_seen(self) -> float:
        """Of the points ahead, the share both cameras see; nan where none is ahead."""
        ahead = int(self.ahead.sum())
        return float((self.seen & self.ahead).sum() / ahead) if ahead else math.nan


def workspace(
    robot: Robot, rng: np.random.Generator, width_px: int, height_px: int, samples: int = 3000
) -> Workspace:
    """The end-effector site at `samples` seeded configurations within the joints' limits (the
    vehicle's own geometry not counted as an obstacle), projected into the stereo pair with MuJoCo's
    pinhole (its fovy, the renderer's `width_px` x `height_px`, square pixels)."""
    model = robot_spec(robot).compile()
    data = mujoco.MjData(model)
    base = int(model.joint(robot.base).qposadr[0])
    data.qpos[base : base + 7] = (0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)
    mujoco.mj_forward(model, data)
    stereo = [model.camera(n).id for n in (robot.stereo_left, robot.stereo_right)]
    centres, frames = data.cam_xpos[stereo].copy(), data.cam_xmat[stereo].reshape(-1, 3, 3).copy()
    lower, upper = _arm_limits_rad(model, robot.arm_joints)
    addresses = [model.joint(n).qposadr[0] for n in robot.arm_joints]
    site = model.site(robot.end_effector_site).id
    points = np.empty((samples, 3))
    for k in range(samples):
        data.qpos[addresses] = rng.uniform(lower, upper)
        mujoco.mj_kinematics(model, data)
        points[k] = data.site_xpos[site]
    seen = np.ones(samples, dtype=bool)
    corners = []
    for cam, centre, frame in zip(stereo, centres, frames, strict=True):
        intrinsics = Intrinsics.from_fovy(width_px, height_px, float(model.cam_fovy[cam]))
        local = (points - centre) @ frame  # camera frame: x right, y up, looking along -z
        depth = -local[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = intrinsics.cx_px + intrinsics.fx_px * local[:, 0] / depth
            v = intrinsics.cy_px - intrinsics.fy_px * local[:, 1] / depth
        seen &= (depth > 0) & (u >= 0) & (u <= width_px) & (v >= 0) & (v <= height_px)
        half_w, half_h = intrinsics.cx_px / intrinsics.fx_px, intrinsics.cy_px / intrinsics.fy_px
        rays = np.array([[sx * half_w, sy * half_h, -1.0] for sx, sy in ((-1, 1), (1, 1), (1, -1), (-1, -1))])
        corners.append(centre + rays @ frame.T)
    outline = _outline(model, data, model.body(robot.base).id)
    across = np.all((points[:, 1:] >= outline[0, 1:]) & (points[:, 1:] <= outline[1, 1:]), axis=1)
    ahead = (points[:, 0] > centres[:, 0].mean()) & across
    return Workspace(points, ahead, seen, outline, centres, np.array(corners))


def _outline(model: mujoco.MjModel, data: mujoco.MjData, body: int) -> np.ndarray:
    """The box around the geoms of `body` (its own, not its children's), as of the last kinematics,
    world frame: lowest and highest corner (2, 3) [m]."""
    corners = []
    for g in np.flatnonzero(model.geom_bodyid == body):
        centre, half = model.geom_aabb[g, :3], model.geom_aabb[g, 3:]
        box = centre + half * np.array(list(itertools.product((-1.0, 1.0), repeat=3)))
        corners.append(data.geom_xpos[g] + box @ data.geom_xmat[g].reshape(3, 3).T)
    stacked = np.concatenate(corners)
    return np.array([stacked.min(axis=0), stacked.max(axis=0)])
