"""Thrusters: allocation of a body wrench to thrusts, and each thruster as a rotor.

The rotor's speed n (a fraction of full, signed) follows its target with a first-order lag,
tau n_dot = n* - n; the target is zero for commands within the dead band and rises from zero
beyond it; thrust is quadratic in the speed, T = T_max n|n|, with T_max forward or reverse (a
propeller pushes less in reverse). The allocation inverts that curve across the dead band, so
the thrust asked for is the thrust delivered, once the rotor has spun up."""

from __future__ import annotations

import mujoco
import numpy as np

from abyss.description.robot import actuated_axes
from abyss.description.robot_file import ThrustersSection


class Thrusters:
    """The vehicle's thrusters, by the robot's allocation matrix. The axes they drive (`actuated`,
    rows of the body wrench fx, fy, fz, mx, my, mz) are those of surge, sway, heave and yaw their
    layout moves (description.robot.actuated_axes); roll and pitch are left to the hydrostatic
    restoring moment."""

    def __init__(self, model: mujoco.MjModel, spec: ThrustersSection, allocation: np.ndarray) -> None:
        self.spec = spec
        self.actuators = np.array([model.actuator(name).id for name in spec.names])
        self.allocation = allocation  # 6 x n: wrench about the centre of mass per N (Robot.allocation)
        self.actuated = np.array(actuated_axes(self.allocation))
        self.actuated.flags.writeable = False
        self.actuated_allocation = self.allocation[self.actuated]  # 4 x n for surge, sway, heave, yaw
        self.pseudo_inverse = np.linalg.pinv(self.actuated_allocation)
        n = len(spec.names)
        self.efficiency = np.ones(n)  # faults: 0 failed, <1 weakened
        self.rotor_speed = np.zeros(n)  # fraction of full, signed

    def allocate(self, wrench_body: np.ndarray) -> np.ndarray:
        """Thrusts [N] for a body wrench [N, N m] (its actuated part), scaled down together
        so that none exceeds its limit in its direction (the direction of the wrench is kept)."""
        return self.allocate_actuated(np.asarray(wrench_body)[self.actuated])

    def allocate_actuated(self, wrench_actuated: np.ndarray) -> np.ndarray:
        """As `allocate`, from the actuated part of the wrench alone (its rows `actuated`)."""
        thrust = self.pseudo_inverse @ wrench_actuated
        excess = (np.abs(thrust) / self.max_thrust_n(thrust)).max()
        return thrust / max(1.0, float(excess))

    def max_thrust_n(self, thrust_n: np.ndarray) -> np.ndarray:
        return np.where(thrust_n >= 0.0, self.spec.forward_max_n, self.spec.reverse_max_n)

    def command(self, thrust_n: np.ndarray) -> np.ndarray:
        """The commands in [-1, 1] that deliver `thrust_n` at steady state: the curve inverted,
        the dead band stepped over."""
        speed = np.sqrt(np.minimum(np.abs(thrust_n) / self.max_thrust_n(thrust_n), 1.0))
        db = self.spec.deadband
        return np.where(speed > 0.0, np.sign(thrust_n) * (db + (1.0 - db) * speed), 0.0)

    def thrust_n(self) -> np.ndarray:
        """What each thruster delivers now [N], faults included."""
        n = self.rotor_speed
        return self.max_thrust_n(n) * n * np.abs(n) * self.efficiency

    def apply(self, data: mujoco.MjData, thrust_n: np.ndarray, dt_s: float) -> None:
        """Command the thrusters for `thrust_n` over the next `dt_s` [s]: the rotors move towards
        their targets (exactly, for a command held over dt_s), and what they push is applied."""
        self.drive(data, self.command(thrust_n), dt_s)

    def drive(self, data: mujoco.MjData, command: np.ndarray, dt_s: float) -> None:
        """As `apply`, from raw commands in [-1, 1] (as an ESC takes them)."""
        db = self.spec.deadband
        command = np.clip(command, -1.0, 1.0)
        target = np.sign(command) * np.maximum(np.abs(command) - db, 0.0) / (1.0 - db)
        self.rotor_speed[:] = target + (self.rotor_speed - target) * np.exp(-dt_s / self.spec.time_constant_s)
        data.ctrl[self.actuators] = self.thrust_n()
