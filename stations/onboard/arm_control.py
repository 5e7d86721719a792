"""The arm's controller on Pinocchio and the shared model (the paper's arm controller): the
end-effector's position, then its orientation, or a moving pose reference (an intervention's),
as tasks of the task-priority solver (task_priority.py), under joint limits and clearance from
obstacles as its constraints; the kinematics of the arm on the vehicle, and the distances to
the obstacles' boxes."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from abyss.common.geometry import rotation_of
from abyss.config.stations import OnboardConfig
from abyss.config.system import MissionConfig
from abyss.description.robot import Robot, robot_mjcf
from abyss.stations.onboard.modes import Mode
from abyss.stations.onboard.task_priority import Constraints, Task, solve_constrained

REACHED_HYSTERESIS = 2.0  # a reached goal is left only beyond this many times its tolerances
XYZW = [1, 2, 3, 0]  # Pinocchio's quaternion order, from w, x, y, z
# a stall: the joints, or the tool in the vehicle's frame, moved less than STALL_SHARE of what the
# controller commanded (along it) for STALL_S, while it commanded at least STALL_MIN_RADPS of the
# joints or STALL_MIN_MPS of the tool; the arm then holds (blocked) instead of pushing on, and the
# low level's servos wind nothing up to swing with once it comes free. The tool's own motion
# catches what the joints' misses: the fingers held against a face while the wrist turns on. In
# the vehicle's frame, not the world's: the vehicle's own motion is not the arm's (judged in the
# world, a vehicle settling on its waypoint with a weakened thruster blocked a free arm); a
# vehicle that yields to the arm's push is caught once it stops yielding
STALL_MIN_RADPS = 0.02
STALL_MIN_MPS = 0.03
STALL_SHARE = 0.25
STALL_S = 0.5


# -- the arm on the vehicle -----------------------------------------------------------------
class ArmKinematics:
    """The robot's model in Pinocchio: poses and world-aligned Jacobians of the arm's frames,
    the decision variables being the arm's joints (and with `whole_body`, the vehicle's
    axes its thrusters move: surge, sway, heave and yaw rate on the shipped robot, of the free
    flyer's body velocity)."""

    def __init__(self, robot: Robot, whole_body: bool = False) -> None:
        self.robot = robot
        self.model = pin.buildModelFromMJCF(str(robot_mjcf(robot)))
        self.data = self.model.createData()
        joints = [self.model.joints[self.model.getJointId(name)] for name in robot.arm_joints]
        self.arm_q = np.array([j.idx_q for j in joints])
        arm_v = [j.idx_v for j in joints]
        self.columns = np.array(arm_v + (list(robot.actuated_axes) if whole_body else []))
        self.lower_rad = self.model.lowerPositionLimit[self.arm_q]
        self.upper_rad = self.model.upperPositionLimit[self.arm_q]
        self.ee = self.model.getFrameId(robot.end_effector_site)
        self.points = [self.model.getFrameId(name) for name in robot.clearance_points]
        self.q = pin.neutral(self.model)

    @property
    def n(self) -> int:
        return len(self.columns)

    def update(
        self, position_m_world: np.ndarray, orientation_wxyz_world: np.ndarray, arm_rad: np.ndarray
    ) -> None:
        self.q[0:3], self.q[3:7] = position_m_world, np.asarray(orientation_wxyz_world)[XYZW]
        self.q[self.arm_q] = arm_rad
        pin.computeJointJacobians(self.model, self.data, self.q)
        pin.updateFramePlacements(self.model, self.data)

    def pose(self, frame: int) -> pin.SE3:
        return self.data.oMf[frame]

    def chain_m_world(self) -> np.ndarray:
        """The arm's joints, base to wrist, then the tool point [m, world], as of the last update."""
        joints = [self.data.oMi[self.model.getJointId(name)].translation for name in self.robot.arm_joints]
        return np.array([*joints, self.data.oMf[self.ee].translation])

    def reach(self) -> tuple[np.ndarray, float]:
        """The shoulder in the vehicle's frame [m] and the arm's reach from it [m]: the sum of
        the segments between its joints and on to the tool point (an upper bound)."""
        saved = self.q.copy()
        self.update(np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0]), self.q[self.arm_q])
        chain = self.chain_m_world()
        self.q = saved
        pin.computeJointJacobians(self.model, self.data, self.q)
        pin.updateFramePlacements(self.model, self.data)
        return chain[0], float(np.linalg.norm(np.diff(chain, axis=0), axis=1).sum())

    def jacobian(self, frame: int) -> np.ndarray:
        """(6, n): linear then angular velocity of the frame, world axes."""
        full = pin.getFrameJacobian(self.model, self.data, frame, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        return full.take(self.columns, axis=1)


_AXES = np.eye(3)
_AXES.flags.writeable = False


def box_distances(points: np.ndarray, boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Signed distances [m] from points (p, 3) to world-aligned boxes (b, 6: centre, half sizes),
    negative inside, (p, b), and their gradients with respect to the points, (p, b, 3)."""
    local = points[:, None, :] - boxes[None, :, :3]
    side = np.where(local >= 0, 1.0, -1.0)
    outside = np.abs(local) - boxes[None, :, 3:]
    clipped = np.maximum(outside, 0.0)
    deepest = outside.max(axis=-1)
    is_outside = deepest > 0
    norm = np.where(is_outside, np.sqrt((clipped**2).sum(axis=-1)), 1.0)
    if is_outside.all():  # the usual case
        return norm, side * clipped / norm[..., None]
    distance = np.where(is_outside, norm, deepest)
    nearest_face = _AXES[outside.argmax(axis=-1)]  # inside
    gradient = side * np.where(is_outside[..., None], clipped / norm[..., None], nearest_face)
    return distance, gradient


def box_distance(point: np.ndarray, box: Sequence[float]) -> tuple[float, np.ndarray]:
    """Signed distance [m] from a point to a world-aligned box (centre, half sizes), negative
    inside, and its gradient with respect to the point."""
    distance, gradient = box_distances(np.asarray(point)[None], np.asarray(box, dtype=float)[None])
    return float(distance[0, 0]), gradient[0, 0]


@dataclass(frozen=True)
class PoseReference:
    """A moving goal for the tool point: where it should be now, and how fast that moves (the
    feedforward) [world]. With `axis_world`, the orientation splits into two tasks: the rotation
    about that axis (an intervention's turn) ranks above the other two directions."""

    position_m_world: np.ndarray
    rotation: np.ndarray  # tool axes to world axes
    velocity_mps_world: np.ndarray = field(default_factory=lambda: np.zeros(3))
    angular_velocity_radps_world: np.ndarray = field(default_factory=lambda: np.zeros(3))
    axis_world: np.ndarray | None = None


@dataclass(frozen=True)
class ArmOutput:
    joint_velocities_radps: np.ndarray  # (6,) model order
    vehicle_velocity: np.ndarray | None  # surge, sway, heave [m/s, body], yaw rate [rad/s]; whole body
    mode: Mode  # idle, moving, reached or hold
    position_error_m_world: np.ndarray
    orientation_error_rad: float
    active: tuple[str, ...]  # constraints that ranked above the goal this step


class ArmController:
    """End-effector position, then orientation, under joint limits and obstacle clearance."""

    def __init__(
        self,
        cfg: OnboardConfig,
        mission: MissionConfig,
        robot: Robot,
        kinematics: ArmKinematics | None = None,
    ):
        self.cfg = cfg
        self.mission = mission
        self.kinematics = kinematics or ArmKinematics(robot, cfg.whole_body)
        self.arm_joints = robot.arm_joints
        self.command_id = -1
        self.goal_position_m_world: np.ndarray | None = None
        self.goal_rotation = np.eye(3)
        self.within_s = 0.0  # how long both errors have been within tolerance
        self.stall = Stall()
        self.joints_s = 0.0  # the simulated time of the joint states last stepped on
        # the constraints' constant parts: each joint's lower then upper limit (h = +q, -q: linear in
        # the joints), then each clearance point against each obstacle
        kin, joints, margin_rad = self.kinematics, len(self.arm_joints), cfg.joint_limit_margin_rad
        self.boxes = np.array(mission.obstacles, dtype=float).reshape(-1, 6)
        clearances = [
            f"{point} clear of obstacle {j}"
            for point in robot.clearance_points
            for j in range(len(self.boxes))
        ]
        self.constraint_names = (
            *(f"{name} {side}" for name in self.arm_joints for side in ("lower", "upper")),
            *clearances,
        )
        self.limit_gradients = np.zeros((2 * joints, kin.n))
        self.limit_gradients[0::2, :joints] = np.eye(joints)
        self.limit_gradients[1::2, :joints] = -np.eye(joints)
        self.constraint_minimums = np.concatenate(
            (
                np.column_stack((kin.lower_rad + margin_rad, -kin.upper_rad + margin_rad)).ravel(),
                np.full(len(clearances), cfg.clearance_m),
            )
        )
        self.speed_limits = np.r_[
            np.full(joints, cfg.max_joint_speed_radps), np.full(3, cfg.max_speed_mps), cfg.max_yaw_rate_radps
        ][: kin.n]
        # the solver's variables: the joints' speeds, and the vehicle's scaled by whole_body_weight
        self.column_scale = np.r_[np.ones(joints), np.full(kin.n - joints, cfg.whole_body_weight)]
        for constant in (
            self.boxes,
            self.limit_gradients,
            self.constraint_minimums,
            self.speed_limits,
            self.column_scale,
        ):
            constant.flags.writeable = False

    def set_goal(
        self, command_id: int, position_m_world: np.ndarray, orientation_wxyz_world: np.ndarray
    ) -> bool:
        if command_id == self.command_id:
            return False
        self.command_id = command_id
        self.goal_position_m_world = np.array(position_m_world, dtype=float)
        self.goal_rotation = rotation_of(orientation_wxyz_world)
        self.within_s = 0.0
        self.stall = Stall()  # a new goal may lead away from what blocked the last
        return True

    def errors(self) -> tuple[np.ndarray, np.ndarray]:
        """Position error [m, world] and orientation error (rotation vector) [rad, world]."""
        assert self.goal_position_m_world is not None
        pose = self.kinematics.pose(self.kinematics.ee)
        return (
            self.goal_position_m_world - pose.translation,
            np.asarray(pin.log3(self.goal_rotation @ pose.rotation.T)),
        )

    def constraints(self, arm_rad: np.ndarray) -> Constraints:
        kin = self.kinematics
        points_m_world = np.array([kin.pose(frame).translation for frame in kin.points])
        linear = np.array([kin.jacobian(frame)[:3] for frame in kin.points])  # (points, 3, n)
        distances_m, gradients = box_distances(points_m_world, self.boxes)  # (points, boxes[, 3])
        clearance_gradients = (gradients @ linear).reshape(-1, kin.n)
        limits_rad = self.limit_gradients[:, : len(self.arm_joints)] @ arm_rad
        return Constraints(
            self.constraint_names,
            np.vstack((self.limit_gradients, clearance_gradients)),
            np.concatenate((limits_rad, distances_m.ravel())),
            self.constraint_minimums,
        )

    def step(
        self,
        position_m_world: np.ndarray,
        orientation_wxyz_world: np.ndarray,
        arm_rad: np.ndarray,
        enabled: bool,
        reference: PoseReference | None = None,
        joints_s: float | None = None,
    ) -> ArmOutput:
        """One period towards the goal, or with `reference` along it instead (the goal kept).
        `joints_s`: the simulated time of `arm_rad` (None: one control period after the last)."""
        kin, cfg = self.kinematics, self.cfg
        kin.update(position_m_world, orientation_wxyz_world, arm_rad)
        zero = np.zeros(len(self.arm_joints))
        if reference is not None:
            return self._follow(reference, arm_rad, enabled)
        if self.goal_position_m_world is None:
            return ArmOutput(zero, None, Mode.IDLE, np.zeros(3), 0.0, ())
        position_error, rotation_error = self.errors()
        angle = _norm(rotation_error)
        # once settled, the goal stays reached within twice the tolerances, so that navigation
        # noise at the tolerance's edge does not make the status flicker
        scale = REACHED_HYSTERESIS if self.within_s >= self.mission.arm_settle_s else 1.0
        within = (
            _norm(position_error) < scale * self.mission.arm_position_tolerance_m
            and angle < scale * self.mission.arm_orientation_tolerance_rad
        )
        self.within_s = self.within_s + cfg.control_period_s if within and enabled else 0.0
        vehicle_rotation = rotation_of(orientation_wxyz_world)
        tool_m_vehicle = vehicle_rotation.T @ (kin.pose(kin.ee).translation - position_m_world)
        self.joints_s = self.joints_s + cfg.control_period_s if joints_s is None else joints_s
        if not enabled:
            self.stall.rest((arm_rad, tool_m_vehicle), self.joints_s)
            return ArmOutput(zero, None, Mode.HOLD, position_error, angle, ())
        if self.stall.judge((arm_rad, tool_m_vehicle), self.joints_s):
            return ArmOutput(zero, None, Mode.BLOCKED, position_error, angle, ())
        jacobian = kin.jacobian(kin.ee)
        tasks = [
            Task(
                "end-effector position",
                jacobian[:3],
                _limit(cfg.kp_ee_position * position_error, cfg.max_ee_speed_mps),
            ),
            Task(
                "end-effector orientation",
                jacobian[3:],
                _limit(cfg.kp_ee_orientation * rotation_error, cfg.max_ee_rate_radps),
            ),
        ]
        reached = self.within_s >= self.mission.arm_settle_s
        out = self._solve(tasks, arm_rad, Mode.REACHED if reached else Mode.MOVING, position_error, angle)
        arm_velocities = out.joint_velocities_radps
        tool_mps_vehicle = vehicle_rotation.T @ (jacobian[:3, : len(self.arm_joints)] @ arm_velocities)
        self.stall.commanded((arm_velocities, tool_mps_vehicle))
        return out

    def _solve(
        self, tasks: list[Task], arm_rad: np.ndarray, mode: Mode, position_error: np.ndarray, angle: float
    ) -> ArmOutput:
        """The tasks under the constraints, within the speed limits; solved in the scaled
        variables (`column_scale`: the least norm weighs the vehicle's against the joints')."""
        kin, cfg, scale = self.kinematics, self.cfg, self.column_scale
        constraints = self.constraints(arm_rad)
        scaled, active, _ = solve_constrained(
            dataclasses.replace(constraints, gradients=constraints.gradients * scale),
            [dataclasses.replace(task, jacobian=task.jacobian * scale) for task in tasks],
            kin.n,
            cfg.kp_constraint,
            cfg.damping,
            cfg.singular_value_threshold,
        )
        xdot = self._within_speed_limits(scaled * scale)
        vehicle = xdot[len(self.arm_joints) :] if cfg.whole_body else None
        return ArmOutput(
            xdot[: len(self.arm_joints)],
            vehicle,
            mode,
            position_error,
            angle,
            tuple(self.constraint_names[i] for i in active),
        )

    def _follow(self, ref: PoseReference, arm_rad: np.ndarray, enabled: bool) -> ArmOutput:
        """Track a moving pose: feedforward plus feedback, under the same constraints. The turn
        about `ref.axis_world` is a task of its own, ranked below the position (which holds the
        handle) and above the rest of the orientation."""
        kin, cfg = self.kinematics, self.cfg
        pose = kin.pose(kin.ee)
        position_error = ref.position_m_world - pose.translation
        rotation_error = np.asarray(pin.log3(ref.rotation @ pose.rotation.T))
        angle = _norm(rotation_error)
        if not enabled:
            return ArmOutput(np.zeros(len(self.arm_joints)), None, Mode.HOLD, position_error, angle, ())
        jacobian = kin.jacobian(kin.ee)
        angular = ref.angular_velocity_radps_world + cfg.kp_ee_orientation * rotation_error
        tasks = [
            Task(
                "end-effector position",
                jacobian[:3],
                _limit(ref.velocity_mps_world + cfg.kp_ee_position * position_error, cfg.max_ee_speed_mps),
            )
        ]
        if ref.axis_world is None:
            tasks.append(
                Task("end-effector orientation", jacobian[3:], _limit(angular, cfg.max_ee_rate_radps))
            )
        else:
            axis = ref.axis_world / np.linalg.norm(ref.axis_world)
            across = np.linalg.svd(axis[None, :])[2][1:]  # two unit rows normal to the axis
            tasks += [
                Task(
                    "turn about the axis",
                    axis[None, :] @ jacobian[3:],
                    np.clip([axis @ angular], -cfg.max_ee_rate_radps, cfg.max_ee_rate_radps),
                ),
                Task(
                    "orientation across the axis",
                    across @ jacobian[3:],
                    _limit(across @ angular, cfg.max_ee_rate_radps),
                ),
            ]
        return self._solve(tasks, arm_rad, Mode.MOVING, position_error, angle)

    def _within_speed_limits(self, xdot: np.ndarray) -> np.ndarray:
        """Scale the whole solution (its direction kept) so that no variable exceeds its limit."""
        worst = float((np.abs(xdot) / self.speed_limits).max())
        return xdot / worst if worst > 1.0 else xdot


class Stall:
    """Commanded motion against measured, period by period, of the joints [rad] and of the tool in
    the vehicle's frame [m] (see STALL_S), over the simulated time between the joint states
    judged: a simulation running behind the wall clock (an overloaded machine) moves the arm
    less per control period, and is no stall. Once blocked, it stays blocked until a new goal."""

    MINIMUMS = (STALL_MIN_RADPS, STALL_MIN_MPS)

    def __init__(self) -> None:
        self.velocities: tuple[np.ndarray, ...] | None = None  # what the last period commanded
        self.from_positions: tuple[np.ndarray, ...] | None = None  # where they were then
        self.from_s = 0.0  # and when [s, the joint states' simulated time]
        self.stalled_s = 0.0
        self.blocked = False

    def rest(self, positions: tuple[np.ndarray, ...], t_s: float) -> None:
        """The arm holds for another reason (failsafe, operator): nothing commanded, nothing judged."""
        self.velocities, self.from_positions, self.from_s, self.stalled_s = None, positions, t_s, 0.0

    def commanded(self, velocities: tuple[np.ndarray, ...]) -> None:
        self.velocities = velocities

    def judge(self, positions: tuple[np.ndarray, ...], t_s: float) -> bool:
        """True if the arm is blocked: the joints or the tool have not followed what was commanded
        since the last judgement, `t_s` the joint states' simulated time."""
        commanded, moved_from, dt_s = self.velocities, self.from_positions, t_s - self.from_s
        if self.blocked or dt_s <= 0.0:  # no newer joint state: nothing to judge yet
            return self.blocked
        self.from_positions, self.from_s = positions, t_s
        if commanded is None or moved_from is None:
            return False
        stalled = False
        for velocity, now, then, minimum in zip(commanded, positions, moved_from, self.MINIMUMS, strict=True):
            speed = _norm(velocity)
            if speed >= minimum:
                stalled |= float((now - then) @ velocity) / (speed * speed * dt_s) < STALL_SHARE
        self.stalled_s = self.stalled_s + dt_s if stalled else 0.0
        self.blocked = self.stalled_s >= STALL_S
        return self.blocked


def _limit(vector: np.ndarray, norm_max: float) -> np.ndarray:
    norm = _norm(vector)
    return vector * (norm_max / norm) if norm > norm_max else vector


def _norm(vector: np.ndarray) -> float:
    """np.linalg.norm of a vector to the bit (the root of its dot product), without that function's
    overhead."""
    return math.sqrt(vector @ vector)
