"""The MuJoCo world and the kinematic low-level vehicle controller: a pure core that
takes a velocity reference and time and returns the navigation state."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np

from common.config import SimulationConfig
from common.geometry import yaw_of
from common.messages import NavState, VelocityRef

MODEL_FILE = Path(__file__).resolve().parents[2] / "common" / "models" / "world.xml"


class World:
    """Steps the physics; the kinematic low level applies the reference velocity directly
    (roll and pitch are held: the vehicle is not actuated in them)."""

    def __init__(self, config: SimulationConfig) -> None:
        self.config = config
        self.model = mujoco.MjModel.from_xml_path(str(MODEL_FILE))
        self.model.opt.timestep = config.physics_step_s
        self.data = mujoco.MjData(self.model)
        self._qpos = self.model.joint("vehicle").qposadr[0]
        self._qvel = self.model.joint("vehicle").dofadr[0]
        self.data.qpos[self._qpos:self._qpos + 3] = config.start_position_m_world
        mujoco.mj_forward(self.model, self.data)

    def step(self, command: VelocityRef | None, period_s: float) -> None:
        """Advance by `period_s` [s] under `command` (None: hold still)."""
        yaw = yaw_of(self.data.qpos[self._qpos + 3:self._qpos + 7])
        c, s = np.cos(yaw), np.sin(yaw)
        level_yaw = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        linear_world = level_yaw @ command.linear_mps_body if command else np.zeros(3)
        yaw_rate = command.yaw_rate_radps if command else 0.0
        for _ in range(round(period_s / self.model.opt.timestep)):
            self.data.qvel[self._qvel:self._qvel + 3] = linear_world
            self.data.qvel[self._qvel + 3:self._qvel + 6] = (0.0, 0.0, yaw_rate)
            mujoco.mj_step(self.model, self.data)

    def nav_state(self) -> NavState:
        quat = self.data.qpos[self._qpos + 3:self._qpos + 7].copy()
        quat /= np.linalg.norm(quat)
        rotation = np.empty(9)
        mujoco.mju_quat2Mat(rotation, quat)
        linear_world = self.data.qvel[self._qvel:self._qvel + 3]
        return NavState(
            position_m_world=self.data.qpos[self._qpos:self._qpos + 3].copy(),
            orientation_wxyz_world=quat,
            velocity_mps_body=rotation.reshape(3, 3).T @ linear_world,
            angular_velocity_radps_body=self.data.qvel[self._qvel + 3:self._qvel + 6].copy(),
            sim_time_s=float(self.data.time),
        )
