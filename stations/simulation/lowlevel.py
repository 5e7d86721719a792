"""The two interchangeable low-level controllers, with the same inputs: a body velocity
reference for the vehicle (surge, sway, heave [m/s], yaw rate [rad/s]) and joint velocity
references for the arm [rad/s] and gripper [m/s].

kinematic: applies the references as the velocities, instantly (validates the high level);
dynamic: PID on the velocity error plus a feed-forward of the vehicle's damping, through the
thruster allocation and the joint motors; with attitude gains, roll and pitch held level too
(attitude.py)."""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from abyss.description.marine import VehicleModel
from abyss.description.robot import COMMANDED_AXES, Robot
from abyss.stations.simulation.attitude import AttitudeHold
from abyss.stations.simulation.thrusters import Thrusters


@dataclass(frozen=True)
class References:
    vehicle_body: np.ndarray  # (4,) surge, sway, heave [m/s], yaw rate [rad/s]
    arm_radps: np.ndarray  # (arm joints,)
    gripper_mps: float

    @staticmethod
    def hold() -> References:
        """Everything still: the arm's references one zero, which broadcasts over however many
        joints the robot's arm has."""
        return References(np.zeros(4), np.zeros(1), 0.0)


class Plant:
    """Index bookkeeping shared by both controllers: where the robot's base, arm and gripper sit."""

    def __init__(self, model: mujoco.MjModel, robot: Robot) -> None:
        joint = model.joint(robot.base)
        self.qpos, self.qvel = joint.qposadr[0], joint.dofadr[0]
        self.arm_dofs = np.array([model.joint(n).dofadr[0] for n in robot.arm_joints])
        self.gripper_dofs = np.array([model.joint(n).dofadr[0] for n in robot.gripper_joints])
        self.arm_motors = np.array([model.actuator(n).id for n in robot.arm_joints])
        self.gripper_motors = np.array([model.actuator(n).id for n in robot.gripper_joints])

    def rotation(self, data: mujoco.MjData) -> np.ndarray:
        rotation = np.empty(9)
        mujoco.mju_quat2Mat(rotation, data.qpos[self.qpos + 3 : self.qpos + 7])
        return rotation.reshape(3, 3)

    def vehicle_velocity_body(self, data: mujoco.MjData) -> np.ndarray:
        """(surge, sway, heave, roll rate, pitch rate, yaw rate) in the body frame."""
        linear = self.rotation(data).T @ data.qvel[self.qvel : self.qvel + 3]  # freejoint: world
        return np.concatenate((linear, data.qvel[self.qvel + 3 : self.qvel + 6]))  # angular: body frame


class Kinematic:
    dynamics = False  # the world integrates positions from these velocities, no forces

    def __init__(self, model: mujoco.MjModel, gains: object, vehicle: object, robot: Robot) -> None:
        self.plant = Plant(model, robot)

    def apply(self, data: mujoco.MjData, ref: References, dt_s: float) -> None:
        p = self.plant
        r = p.rotation(data)
        # level the vehicle: no roll or pitch rate, yaw rate about the world's vertical
        data.qvel[p.qvel : p.qvel + 3] = r @ ref.vehicle_body[:3]
        data.qvel[p.qvel + 3 : p.qvel + 6] = r.T @ np.array([0.0, 0.0, ref.vehicle_body[3]])
        data.qvel[p.arm_dofs] = ref.arm_radps
        data.qvel[p.gripper_dofs] = ref.gripper_mps
        data.ctrl[:] = 0.0


@dataclass(frozen=True)
class PidGains:
    vehicle_kp: tuple[float, ...]  # surge, sway, heave [N/(m/s)], yaw [N m/(rad/s)]
    vehicle_ki: tuple[float, ...]
    vehicle_kd: tuple[float, ...]
    arm_kp: float  # [N m/(rad/s)], > 0
    arm_ki: float
    gripper_kp: float  # [N/(m/s)]
    attitude_kp: tuple[float, float] = (0.0, 0.0)  # roll, pitch [N m/rad]: attitude.py; 0 passive
    attitude_kd: tuple[float, float] = (0.0, 0.0)  # [N m/(rad/s)]


class Dynamic:
    dynamics = True

    def __init__(self, model: mujoco.MjModel, gains: PidGains, vehicle: VehicleModel, robot: Robot) -> None:
        self.plant = Plant(model, robot)
        self.thrusters = Thrusters(model, vehicle.thrusters, robot.allocation)
        actuated = self.thrusters.actuated
        # the PID runs on the commanded axes (surge, sway, heave, yaw); the allocation takes those
        # the thrusters move (all four on the shipped layout)
        self.allocated = np.array([COMMANDED_AXES.index(int(a)) for a in actuated])
        self.damping = (
            vehicle.linear_damping[list(COMMANDED_AXES)],
            vehicle.quadratic_damping[list(COMMANDED_AXES)],
        )
        self.gains = gains
        self._vehicle_kp, self._vehicle_ki, self._vehicle_kd = (
            np.array(gains.vehicle_kp),
            np.array(gains.vehicle_ki),
            np.array(gains.vehicle_kd),
        )
        self.attitude = AttitudeHold(self.thrusters, gains.attitude_kp, gains.attitude_kd)
        self.vehicle_integral = np.zeros(4)
        self.vehicle_error = np.zeros(4)
        self.arm_integral = np.zeros(len(robot.arm_joints))
        self.arm_force_limit = model.actuator_forcerange[self.plant.arm_motors, 1]
        servos = ((self.plant.arm_motors, gains.arm_kp), (self.plant.gripper_motors, gains.gripper_kp))
        for motors, kv in servos:
            model.actuator_gainprm[motors, 0] = kv  # velocity servo: kv * ctrl - kv * qdot
            model.actuator_biasprm[motors, 2] = -kv

    def apply(self, data: mujoco.MjData, ref: References, dt_s: float) -> None:
        p, g = self.plant, self.gains
        velocity6 = p.vehicle_velocity_body(data)
        velocity = velocity6[list(COMMANDED_AXES)]
        error = ref.vehicle_body - velocity
        derivative = (error - self.vehicle_error) / dt_s
        self.vehicle_error[:] = error
        # feed-forward of the marine model's damping at the reference: the integral is left only
        # the model's error and the current to take up, not the whole drag (a slow pole otherwise)
        linear, quadratic = self.damping
        feed_forward = (linear + quadratic * np.abs(ref.vehicle_body)) * ref.vehicle_body
        wrench4 = feed_forward + self._vehicle_kp * error + self._vehicle_kd * derivative
        candidate = self.vehicle_integral + error * dt_s
        wrench4 = wrench4 + self._vehicle_ki * candidate
        allocated = wrench4[self.allocated]
        if self.attitude.held:  # roll and pitch held level too, through the same thrusters
            allocated = np.r_[allocated, self.attitude.moment(p.rotation(data), velocity6[3:5])]
            thrust = self.attitude.allocate(allocated)
            shortfall = np.abs(self.attitude.allocation @ thrust - allocated)
        else:
            thrust = self.thrusters.allocate_actuated(allocated)
            shortfall = np.abs(self.thrusters.actuated_allocation @ thrust - allocated)
        if (shortfall <= 1e-6 + 1e-6 * np.abs(allocated)).all():  # np.allclose's test, rtol = atol = 1e-6
            self.vehicle_integral[:] = candidate  # anti-windup: integrate only when not saturated
        self.thrusters.apply(data, thrust, dt_s)
        # arm: the proportional part is MuJoCo's implicit velocity servo (kv = arm_kp); the
        # integral part shifts its set point, so torque = kp e + ki integral(e)
        arm_error = ref.arm_radps - data.qvel[p.arm_dofs]
        candidate = self.arm_integral + arm_error * dt_s
        if (np.abs(g.arm_kp * arm_error + g.arm_ki * candidate) < self.arm_force_limit).all():
            self.arm_integral[:] = candidate  # anti-windup
        data.ctrl[p.arm_motors] = ref.arm_radps + g.arm_ki / g.arm_kp * self.arm_integral
        data.ctrl[p.gripper_motors] = ref.gripper_mps


LOW_LEVELS: dict[str, type[Kinematic] | type[Dynamic]] = {"kinematic": Kinematic, "dynamic": Dynamic}
