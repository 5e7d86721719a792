"""Thruster allocation: a body wrench to thrusts, with saturation, and thruster faults."""

from __future__ import annotations

import mujoco
import numpy as np

from abyss.common.models import THRUSTERS

# The vehicle has thrust in surge, sway, heave and yaw; roll and pitch are left to its
# hydrostatic restoring moment, as on the original vehicle.
ACTUATED = (0, 1, 2, 5)  # rows of the body wrench (fx, fy, fz, mx, my, mz)


class Thrusters:
    def __init__(self, model: mujoco.MjModel, body: str = "vehicle") -> None:
        b = model.body(body).id
        com = model.body_ipos[b]
        self.actuators = [model.actuator(name).id for name in THRUSTERS]
        self.max_thrust_n = np.array([model.actuator_ctrlrange[a, 1] for a in self.actuators])
        columns = []
        for name in THRUSTERS:
            site = model.site(name)
            if site.bodyid[0] != b:
                raise ValueError(f"thruster {name} is not on {body}")
            rotation = np.empty(9)
            mujoco.mju_quat2Mat(rotation, site.quat)
            axis = rotation.reshape(3, 3)[:, 2]
            columns.append(np.r_[axis, np.cross(site.pos - com, axis)])
        self.allocation = np.array(columns).T  # 6 x n: wrench about the centre of mass per N
        self._pinv = np.linalg.pinv(self.allocation[list(ACTUATED)])
        self.efficiency = np.ones(len(THRUSTERS))  # faults: 0 failed, <1 weakened

    def allocate(self, wrench_body: np.ndarray) -> np.ndarray:
        """Thrusts [N] for a body wrench [N, N m] (its actuated part), scaled down together
        so that none exceeds its limit (the direction of the wrench is kept)."""
        thrust = self._pinv @ np.asarray(wrench_body)[list(ACTUATED)]
        excess = np.max(np.abs(thrust) / self.max_thrust_n)
        return thrust / max(1.0, float(excess))

    def apply(self, data: mujoco.MjData, thrust_n: np.ndarray) -> None:
        """Command the thrusters; a failed or weakened one delivers only its share."""
        data.ctrl[self.actuators] = thrust_n * self.efficiency
