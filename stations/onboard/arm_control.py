"""Task-priority inverse kinematics for the arm on Pinocchio and the shared model (the paper's
arm controller).

    qdot = J1+ K1 e1 + N1 (J2 N1)+ (K2 e2 - J2 qdot1) + ... + N1..n-1 (Jn N1..n-1)+ (...)

Each task is solved in the null space of the augmented Jacobian of the tasks above it, so a
lower task never disturbs a higher one; the pseudo-inverse is damped near singularities.
Safety constraints (joint limits, clearance from obstacles) are inequalities in the
velocity-damper form hdot >= -k (h - h_min): they join the top of the stack only while the
solution without them would break them (set-based task priority), so they cost the mission
nothing while it is safe, and they rank above it when it is not.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from abyss.common.config import MissionConfig, OnboardConfig
from abyss.common.geometry import rotation_of
from abyss.common.models import ARM_JOINTS, END_EFFECTOR_SITE, ROBOT_FILE

CLEARANCE_POINTS = ("arm_link3", "arm_link5", END_EFFECTOR_SITE)  # elbow, wrist, end-effector
REACHED_HYSTERESIS = 2.0  # a reached goal is left only beyond this many times its tolerances
VEHICLE_DOFS = (0, 1, 2, 5)  # of the free flyer's body velocity: surge, sway, heave, yaw rate


# -- the solver ---------------------------------------------------------------------------
@dataclass(frozen=True)
class Task:
    """Rows of a task: J xdot = velocity, in the decision variables x."""

    name: str
    jacobian: np.ndarray  # (m, n)
    velocity: np.ndarray  # (m,)


@dataclass(frozen=True, eq=False)  # identity: the solver asks which ones are active
class Constraint:
    """h(x) >= minimum, enforced as the velocity damper hdot >= -k (h - minimum)."""

    name: str
    gradient: np.ndarray  # (n,) dh/dx
    value: float
    minimum: float

    def rate(self, k: float) -> float:
        return -k * (self.value - self.minimum)

    def broken_by(self, xdot: np.ndarray, k: float) -> bool:
        return float(self.gradient @ xdot) < self.rate(k) - 1e-12

    def task(self, k: float) -> Task:
        return Task(self.name, self.gradient[None, :], np.array([self.rate(k)]))


def damped_pinv(jacobian: np.ndarray, damping: float, threshold: float) -> np.ndarray:
    """Pseudo-inverse with damping that grows as the smallest singular value falls below
    `threshold`, up to `damping` at a singularity (Nakamura and Hanafusa; Maciejewski)."""
    u, s, vt = np.linalg.svd(jacobian, full_matrices=False)
    smallest = float(s[-1]) if s.size else 0.0
    damping2 = damping**2 * (1.0 - (smallest / threshold) ** 2) if smallest < threshold else 0.0
    denominator = s**2 + damping2
    inverse = np.divide(s, denominator, out=np.zeros_like(s), where=denominator > 1e-300)
    return (vt.T * inverse) @ u.T


def null_projector(jacobian: np.ndarray) -> np.ndarray:
    """The orthogonal projector onto the null space of `jacobian`."""
    n = jacobian.shape[1]
    return np.eye(n) - np.linalg.pinv(jacobian, rcond=1e-10) @ jacobian


def solve(tasks: Sequence[Task], n: int, damping: float, threshold: float) -> list[np.ndarray]:
    """Each task's contribution to xdot, in priority order; xdot is their sum."""
    xdot, projector, above = np.zeros(n), np.eye(n), np.zeros((0, n))
    contributions = []
    for task in tasks:
        inverse = damped_pinv(task.jacobian @ projector, damping, threshold)
        step = projector @ (inverse @ (task.velocity - task.jacobian @ xdot))
        xdot = xdot + step
        contributions.append(step)
        above = np.vstack([above, task.jacobian])
        projector = null_projector(above)
    return contributions


def solve_constrained(
        constraints: Sequence[Constraint], tasks: Sequence[Task], n: int, k: float, damping: float,
        threshold: float) -> tuple[np.ndarray, list[Constraint], list[np.ndarray]]:
    """Set-based task priority: the constraints that the solution would break join the top
    of the stack until none is broken. Returns xdot, the active constraints and every
    task's contribution (the active constraints' first)."""
    active: list[Constraint] = []
    while True:
        contributions = solve([c.task(k) for c in active] + list(tasks), n, damping, threshold)
        xdot = np.sum(contributions, axis=0) if contributions else np.zeros(n)
        broken = [c for c in constraints if c not in active and c.broken_by(xdot, k)]
        if not broken:
            return xdot, active, contributions
        active.append(min(broken, key=lambda c: float(c.gradient @ xdot) - c.rate(k)))


# -- the arm on the vehicle -----------------------------------------------------------------
class ArmKinematics:
    """The shared model in Pinocchio: poses and world-aligned Jacobians of the arm's frames,
    the decision variables being the arm's joints (and with `whole_body`, the vehicle's
    surge, sway, heave and yaw rate)."""

    def __init__(self, whole_body: bool = False) -> None:
        self.model = pin.buildModelFromMJCF(str(ROBOT_FILE))
        self.data = self.model.createData()
        joints = [self.model.joints[self.model.getJointId(name)] for name in ARM_JOINTS]
        self.arm_q = np.array([j.idx_q for j in joints])
        arm_v = [j.idx_v for j in joints]
        self.columns = np.array(arm_v + (list(VEHICLE_DOFS) if whole_body else []))
        self.lower_rad = self.model.lowerPositionLimit[self.arm_q]
        self.upper_rad = self.model.upperPositionLimit[self.arm_q]
        self.ee = self.model.getFrameId(END_EFFECTOR_SITE)
        self.points = [self.model.getFrameId(name) for name in CLEARANCE_POINTS]
        self.q = pin.neutral(self.model)

    @property
    def n(self) -> int:
        return len(self.columns)

    def update(self, position_m_world: np.ndarray, orientation_wxyz_world: np.ndarray,
               arm_rad: np.ndarray) -> None:
        w, x, y, z = orientation_wxyz_world
        self.q[0:3], self.q[3:7] = position_m_world, (x, y, z, w)
        self.q[self.arm_q] = arm_rad
        pin.computeJointJacobians(self.model, self.data, self.q)
        pin.updateFramePlacements(self.model, self.data)

    def pose(self, frame: int) -> pin.SE3:
        return self.data.oMf[frame]

    def chain_m_world(self) -> np.ndarray:
        """The arm's joints, base to wrist, then the tool point [m, world], as of the last update."""
        joints = [self.data.oMi[self.model.getJointId(name)].translation for name in ARM_JOINTS]
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
        return full[:, self.columns]


def box_distance(point: np.ndarray, box: Sequence[float]) -> tuple[float, np.ndarray]:
    """Signed distance [m] from a point to a world-aligned box (centre, half sizes), negative
    inside, and its gradient with respect to the point."""
    local = point - np.asarray(box[:3])
    outside = np.abs(local) - np.asarray(box[3:])
    if np.any(outside > 0):
        clipped = np.maximum(outside, 0.0)
        distance = float(np.linalg.norm(clipped))
        return distance, np.sign(local) * clipped / distance
    axis = int(np.argmax(outside))
    gradient = np.zeros(3)
    gradient[axis] = 1.0 if local[axis] >= 0 else -1.0
    return float(outside[axis]), gradient


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
    mode: str  # idle | moving | reached | hold
    position_error_m_world: np.ndarray
    orientation_error_rad: float
    active: tuple[str, ...]  # constraints that ranked above the goal this step


class ArmController:
    """End-effector position, then orientation, under joint limits and obstacle clearance."""

    def __init__(self, cfg: OnboardConfig, mission: MissionConfig, kinematics: ArmKinematics | None = None):
        self.cfg = cfg
        self.mission = mission
        self.kinematics = kinematics or ArmKinematics(cfg.whole_body)
        self.command_id = -1
        self.goal_position_m_world: np.ndarray | None = None
        self.goal_rotation = np.eye(3)
        self.within_s = 0.0  # how long both errors have been within tolerance

    def set_goal(self, command_id: int, position_m_world: np.ndarray,
                 orientation_wxyz_world: np.ndarray) -> bool:
        if command_id == self.command_id:
            return False
        self.command_id = command_id
        self.goal_position_m_world = np.array(position_m_world, dtype=float)
        self.goal_rotation = rotation_of(orientation_wxyz_world)
        self.within_s = 0.0
        return True

    def errors(self) -> tuple[np.ndarray, np.ndarray]:
        """Position error [m, world] and orientation error (rotation vector) [rad, world]."""
        assert self.goal_position_m_world is not None
        pose = self.kinematics.pose(self.kinematics.ee)
        return (self.goal_position_m_world - pose.translation,
                np.asarray(pin.log3(self.goal_rotation @ pose.rotation.T)))

    def constraints(self, arm_rad: np.ndarray) -> list[Constraint]:
        kin, cfg, n = self.kinematics, self.cfg, self.kinematics.n
        found = []
        for i, name in enumerate(ARM_JOINTS):
            unit = np.zeros(n)
            unit[i] = 1.0
            found.append(Constraint(f"{name} lower", unit, float(arm_rad[i]),
                                    float(kin.lower_rad[i]) + cfg.joint_limit_margin_rad))
            found.append(Constraint(f"{name} upper", -unit, -float(arm_rad[i]),
                                    -float(kin.upper_rad[i]) + cfg.joint_limit_margin_rad))
        for point, frame in zip(CLEARANCE_POINTS, kin.points, strict=True):
            position = kin.pose(frame).translation
            linear = kin.jacobian(frame)[:3]
            for j, box in enumerate(self.mission.obstacles):
                distance, gradient = box_distance(position, box)
                found.append(Constraint(f"{point} clear of obstacle {j}", gradient @ linear, distance,
                                        cfg.clearance_m))
        return found

    def step(self, position_m_world: np.ndarray, orientation_wxyz_world: np.ndarray, arm_rad: np.ndarray,
             enabled: bool, reference: PoseReference | None = None) -> ArmOutput:
        """One period towards the goal, or with `reference` along it instead (the goal kept)."""
        kin, cfg = self.kinematics, self.cfg
        kin.update(position_m_world, orientation_wxyz_world, arm_rad)
        zero = np.zeros(len(ARM_JOINTS))
        if reference is not None:
            return self._follow(reference, arm_rad, enabled)
        if self.goal_position_m_world is None:
            return ArmOutput(zero, None, "idle", np.zeros(3), 0.0, ())
        position_error, rotation_error = self.errors()
        angle = float(np.linalg.norm(rotation_error))
        # once settled, the goal stays reached within twice the tolerances, so that navigation
        # noise at the tolerance's edge does not make the status flicker
        scale = REACHED_HYSTERESIS if self.within_s >= self.mission.arm_settle_s else 1.0
        within = (np.linalg.norm(position_error) < scale * self.mission.arm_position_tolerance_m
                  and angle < scale * self.mission.arm_orientation_tolerance_rad)
        self.within_s = self.within_s + cfg.control_period_s if within and enabled else 0.0
        if not enabled:
            return ArmOutput(zero, None, "hold", position_error, angle, ())
        jacobian = kin.jacobian(kin.ee)
        tasks = [Task("end-effector position", jacobian[:3],
                      _limit(cfg.kp_ee_position * position_error, cfg.max_ee_speed_mps)),
                 Task("end-effector orientation", jacobian[3:],
                      _limit(cfg.kp_ee_orientation * rotation_error, cfg.max_ee_rate_radps))]
        reached = self.within_s >= self.mission.arm_settle_s
        return self._solve(tasks, arm_rad, "reached" if reached else "moving", position_error, angle)

    def _solve(self, tasks: list[Task], arm_rad: np.ndarray, mode: str, position_error: np.ndarray,
               angle: float) -> ArmOutput:
        """The tasks under the constraints, within the speed limits."""
        kin, cfg = self.kinematics, self.cfg
        xdot, active, _ = solve_constrained(self.constraints(arm_rad), tasks, kin.n, cfg.kp_constraint,
                                            cfg.damping, cfg.singular_value_threshold)
        xdot = self._within_speed_limits(xdot)
        vehicle = xdot[len(ARM_JOINTS):] if cfg.whole_body else None
        return ArmOutput(xdot[:len(ARM_JOINTS)], vehicle, mode, position_error, angle,
                         tuple(c.name for c in active))

    def _follow(self, ref: PoseReference, arm_rad: np.ndarray, enabled: bool) -> ArmOutput:
        """Track a moving pose: feedforward plus feedback, under the same constraints. The turn
        about `ref.axis_world` is a task of its own, ranked below the position (which holds the
        handle) and above the rest of the orientation."""
        kin, cfg = self.kinematics, self.cfg
        pose = kin.pose(kin.ee)
        position_error = ref.position_m_world - pose.translation
        rotation_error = np.asarray(pin.log3(ref.rotation @ pose.rotation.T))
        angle = float(np.linalg.norm(rotation_error))
        if not enabled:
            return ArmOutput(np.zeros(len(ARM_JOINTS)), None, "hold", position_error, angle, ())
        jacobian = kin.jacobian(kin.ee)
        angular = ref.angular_velocity_radps_world + cfg.kp_ee_orientation * rotation_error
        tasks = [Task("end-effector position", jacobian[:3], _limit(
            ref.velocity_mps_world + cfg.kp_ee_position * position_error, cfg.max_ee_speed_mps))]
        if ref.axis_world is None:
            tasks.append(Task("end-effector orientation", jacobian[3:],
                              _limit(angular, cfg.max_ee_rate_radps)))
        else:
            axis = ref.axis_world / np.linalg.norm(ref.axis_world)
            across = np.linalg.svd(axis[None, :])[2][1:]  # two unit rows normal to the axis
            tasks += [Task("turn about the axis", axis[None, :] @ jacobian[3:],
                           np.clip([axis @ angular], -cfg.max_ee_rate_radps, cfg.max_ee_rate_radps)),
                      Task("orientation across the axis", across @ jacobian[3:],
                           _limit(across @ angular, cfg.max_ee_rate_radps))]
        return self._solve(tasks, arm_rad, "moving", position_error, angle)

    def _within_speed_limits(self, xdot: np.ndarray) -> np.ndarray:
        """Scale the whole solution (its direction kept) so that no variable exceeds its limit."""
        cfg = self.cfg
        limits = np.r_[np.full(len(ARM_JOINTS), cfg.max_joint_speed_radps),
                       np.full(3, cfg.max_speed_mps), cfg.max_yaw_rate_radps][:len(xdot)]
        worst = float(np.max(np.abs(xdot) / limits))
        return xdot / worst if worst > 1.0 else xdot


def _limit(vector: np.ndarray, norm_max: float) -> np.ndarray:
    norm = float(np.linalg.norm(vector))
    return vector * (norm_max / norm) if norm > norm_max else vector
