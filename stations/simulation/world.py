"""The simulated world: MuJoCo physics, marine forces, thrusters, the low-level controller,
navigation sensors and faults. A pure core: references and time in, states out."""

from __future__ import annotations

import io
from pathlib import Path

import mujoco
import numpy as np

from abyss.common.errors import ConfigError
from abyss.common.runfiles import write_whole
from abyss.config.simulation import SimulationConfig
from abyss.description.gains import robot_gains
from abyss.description.robot import Robot, place_at_start, robot_at
from abyss.description.site import site_at, world_model
from abyss.interface.faults import ModelNames, model_names
from abyss.interface.messages import (
    ArmVelocityRef,
    JointState,
    NavState,
    PanelState,
    VelocityRef,
)
from abyss.stations.simulation.lowlevel import LOW_LEVELS, Dynamic, PidGains, References
from abyss.stations.simulation.marine import Current
from abyss.stations.simulation.native import LowLevel
from abyss.stations.simulation.nav_sensors import DvlBeams, Navigation
from abyss.stations.simulation.physics import MarinePhysics
from abyss.stations.simulation.strips import ArmStrips

STATE = mujoco.mjtState.mjSTATE_INTEGRATION  # what a restarted simulation resumes from


def references(vehicle: VelocityRef | None, arm: ArmVelocityRef | None) -> References:
    """The low level's inputs; a missing (or stale) command holds that part still."""
    hold = References.hold()
    return References(
        np.r_[vehicle.linear_mps_body, vehicle.yaw_rate_radps] if vehicle else hold.vehicle_body,
        np.array(arm.joint_velocities_radps) if arm else hold.arm_radps,
        arm.gripper_velocity_mps if arm else 0.0,
    )


def _gains(config: SimulationConfig, robot: Robot) -> PidGains:
    """The low level's gains: the configuration's, the vehicle's loops the robot's unless it sets them."""
    kp, ki = robot_gains(robot)
    return PidGains(
        config.vehicle_kp or kp,
        config.vehicle_ki or ki,
        config.vehicle_kd,
        config.arm_kp,
        config.arm_ki,
        config.gripper_kp,
        config.attitude_kp,
        config.attitude_kd,
    )


class World:
    def __init__(self, config: SimulationConfig, rng: np.random.Generator) -> None:
        self.config = config
        self.robot = robot = robot_at(config.robot)
        self.site = site_at(config.site)
        self.model = world_model(robot, self.site)
        self.model.opt.timestep = config.physics_step_s
        self.data = mujoco.MjData(self.model)
        self.vehicle = robot.marine
        self.gains = _gains(config, robot)
        self.controller = LOW_LEVELS[config.low_level](self.model, self.gains, self.vehicle, robot)
        self.plant = self.controller.plant
        self.physics = MarinePhysics(
            self.model,
            self.data,
            robot,
            config.hydrodynamics,
            config.arm_hydrodynamics,
            in_c=self.controller.dynamics,
        )
        self.native_low_level: LowLevel | None = None
        self._bind_native()
        self.current = Current(
            config.current_profile, config.current_sigma_mps, config.current_time_constant_s, rng
        )
        self.water_mps_world = np.zeros(3)  # the current where the vehicle is
        self.navigation = Navigation(config, rng, robot.nav_sensors)
        self.faults: dict[str, float] = {}
        self._index_parts()
        place_at_start(self.model, self.data.qpos, robot, config.start_position_m_world, config.start_yaw_rad)
        mujoco.mj_forward(self.model, self.data)
        self.dvl = DvlBeams(
            self.model,
            self.model.body(robot.base).id,
            config.dvl_min_altitude_m,
            config.dvl_max_altitude_m,
            robot.nav_sensors.dvl,
        )

    def _index_parts(self) -> None:
        """Where the panel's parts, the fingers and the dofs that move of themselves sit in the model."""
        self.parts = self.site.panel.part_names
        self._part_qpos = np.array([self.model.joint(n).qposadr[0] for n in self.parts])
        self._part_joints = np.array([self.model.joint(n).id for n in self.parts])
        self._part_range_rad = self.model.jnt_range[self._part_joints].copy()
        self._part_bodies = np.array([self.model.body(n).id for n in self.parts])
        self._finger_bodies = {int(self.model.joint(n).bodyid[0]) for n in self.robot.gripper_joints}
        robot_dofs = np.r_[
            np.arange(self.plant.qvel, self.plant.qvel + 6), self.plant.arm_dofs, self.plant.gripper_dofs
        ]
        self._passive_dofs = np.setdiff1d(np.arange(self.model.nv), robot_dofs)

    def _bind_native(self) -> None:
        """The dynamic low level in C (native.py) where the strip model carries the whole arm (alike
        to rounding), with the per-step terms in C; None where it runs in Python."""
        physics = self.physics
        self.native_low_level = (
            LowLevel.of(self.controller, physics.strips)
            if physics.marine is not None and not physics.buoyancy_apart and not physics.mujoco_fluid
            else None
        )

    def use_strips(self, strips: ArmStrips) -> None:
        """Another strip model of the arm (other coefficients: tests, benches), C's with it."""
        self.physics.use_strips(strips)
        self._bind_native()

    def step(self, refs: References, period_s: float) -> None:
        """Advance by `period_s` [s] (a whole number of physics steps)."""
        m, d = self.model, self.data
        dt = m.opt.timestep
        every = round(self.config.low_level_period_s / dt)
        if not self.controller.dynamics:  # kinematic: positions follow the velocities exactly
            for i in range(round(period_s / dt)):
                if i % every == 0:
                    self.controller.apply(d, refs, dt * every)
                d.qvel[self._passive_dofs] = 0.0  # nothing else moves
                mujoco.mj_integratePos(m, d.qpos, d.qvel, dt)
                d.time += dt
            mujoco.mj_forward(m, d)
            return
        steps = round(period_s / dt)
        for start in range(0, steps, every):  # the low level runs at its own rate; its outputs hold between
            self._low_level(refs, dt * every)
            self.physics.step(self.water_mps_world, min(every, steps - start))

    def step_thrusts(self, thrust_n: np.ndarray, period_s: float, arm: References | None = None) -> None:
        """Advance by `period_s` [s] with the thrusters commanded open loop, as an autopilot outside
        drives them (ArduPilot's JSON backend: stations/simulation/json_backend.py), the arm and the
        gripper at `arm`'s velocities by their joints' servos (held still without); the dynamic low
        level only."""
        if not isinstance(self.controller, Dynamic):
            raise ConfigError(
                "simulation.low_level", "kinematic: an autopilot's thrusts need the dynamic low level"
            )
        m, d = self.model, self.data
        dt = m.opt.timestep
        every = round(self.config.low_level_period_s / dt)
        steps = round(period_s / dt)
        thrusters, plant = self.controller.thrusters, self.plant
        for start in range(0, steps, every):
            self.current.advance(d.time)
            self.water_mps_world = self.current.velocity_mps_world(d.qpos[plant.qpos + 2])
            thrusters.apply(d, thrust_n, dt * every)
            d.ctrl[plant.arm_motors] = 0.0 if arm is None else arm.arm_radps  # velocity servos
            d.ctrl[plant.gripper_motors] = 0.0 if arm is None else arm.gripper_mps
            self.physics.forces(self.water_mps_world)
            self.physics.step(self.water_mps_world, min(every, steps - start))

    def _low_level(self, refs: References, period_s: float) -> None:
        """The controllers, the current, and the marine forces held until the next update."""
        d = self.data
        self.current.advance(d.time)
        self.water_mps_world = self.current.velocity_mps_world(d.qpos[self.plant.qpos + 2])
        if self.native_low_level is not None:  # the controllers and the arm's forces, one call
            self.native_low_level.apply(d, refs, self.water_mps_world, period_s)
            return
        self.controller.apply(d, refs, period_s)
        self.physics.forces(self.water_mps_world)

    @property
    def runs_in(self) -> str:
        """Where the physics runs, for summary.json: "c" (the per-step terms and the low level),
        "c-steps" (the per-step terms alone), "python", "kinematic" (no forces); runs replay alike
        only on the same."""
        if not self.controller.dynamics:
            return "kinematic"
        if self.physics.marine is None:
            return "python"
        return "c" if self.native_low_level is not None else "c-steps"

    # -- outputs -------------------------------------------------------------------------
    def truth(self) -> NavState:
        p = self.plant.qpos
        quat = self.data.qpos[p + 3 : p + 7] / np.linalg.norm(self.data.qpos[p + 3 : p + 7])
        velocity = self.plant.vehicle_velocity_body(self.data)
        position, t = self.data.qpos[p : p + 3].copy(), float(self.data.time)
        return NavState(
            position, quat, velocity[:3], velocity[3:], t, usbl_time_s=t, depth_m=float(-position[2])
        )

    def nav(self) -> NavState:
        """The sensors' readings now; once every control period (a USBL fix is due by the clock)."""
        return self.navigation.measure(self.truth(), self.dvl.bottom_lock(self.data))

    def joints(self) -> JointState:
        d, p = self.data, self.plant
        return JointState(
            positions_rad=np.array([d.qpos[self.model.joint(n).qposadr[0]] for n in self.robot.arm_joints]),
            velocities_radps=d.qvel[p.arm_dofs].copy(),
            gripper_opening_m=float(
                np.clip(
                    sum(d.qpos[self.model.joint(n).qposadr[0]] for n in self.robot.gripper_joints), 0.0, 1.0
                )
            ),
            sim_time_s=float(d.time),
            gripper_force_n=float(np.mean(np.abs(d.actuator_force[p.gripper_motors]))),
        )

    def panel(self) -> PanelState:
        """The valves' and levers' angles, and how hard the fingers press on each (the normal
        force of their contacts)."""
        m, d = self.model, self.data
        force_n = np.zeros(len(self.parts))
        wrench = np.zeros(6)
        for i in range(d.ncon):
            contact = d.contact[i]
            bodies = {int(m.geom_bodyid[contact.geom1]), int(m.geom_bodyid[contact.geom2])}
            if not bodies & self._finger_bodies:
                continue
            for j, body in enumerate(self._part_bodies):
                if body in bodies:
                    mujoco.mj_contactForce(m, d, i, wrench)
                    force_n[j] += abs(wrench[0])  # along the contact normal
        return PanelState(self.parts, d.qpos[self._part_qpos].copy(), force_n, float(d.time))

    # -- restarts ------------------------------------------------------------------------
    def save_state(self, path: Path) -> None:
        """The whole integration state (time, positions, velocities, controls), written whole
        and renamed: a simulation killed at any moment leaves a state to resume from."""
        state = np.empty(mujoco.mj_stateSize(self.model, STATE))
        mujoco.mj_getState(self.model, self.data, state, STATE)
        buffer = io.BytesIO()
        np.save(buffer, state)
        write_whole(path, buffer.getvalue())

    def resume(self, path: Path) -> bool:
        """Go on from a state `save_state` left; False (and nothing changed) if there is none
        or it is of another model."""
        try:
            state = np.load(path)
        except (OSError, ValueError, EOFError):  # none, or cut short (a crash before the rename hit disk)
            return False
        if (
            not isinstance(state, np.ndarray)
            or state.shape != (mujoco.mj_stateSize(self.model, STATE),)
            or not np.all(np.isfinite(state))
        ):
            return False
        mujoco.mj_setState(self.model, self.data, state, STATE)
        mujoco.mj_forward(self.model, self.data)
        return True

    # -- faults --------------------------------------------------------------------------
    def model_names(self) -> ModelNames:
        """The names of this world's parts that faults target (its robot's thrusters, cameras and
        navigation sensors, the panel's parts)."""
        return model_names(self.robot.spec, self.site.panel)
