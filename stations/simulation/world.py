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
from abyss.stations.simulation.hydrodynamics import Fossen
from abyss.stations.simulation.lowlevel import LOW_LEVELS, PidGains, References
from abyss.stations.simulation.marine import WATER_DENSITY_KGPM3, Buoyancy, Current, wet_geoms
from abyss.stations.simulation.native import LowLevel, Marine
from abyss.stations.simulation.nav_sensors import DvlBeams, Navigation
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


def _arm_strips(model: mujoco.MjModel, buoyancy: Buoyancy, base: str) -> ArmStrips:
    """The strip model of the arm (every wet body but the vehicle, `base`), in place of MuJoCo's
    fluid model of its geoms; ConfigError where a wet geom has a shape it has no member for."""
    wet = wet_geoms(model)
    vehicle = model.body(base).id
    arm = sorted({int(b) for b in model.geom_bodyid[wet]} - {vehicle})
    try:
        strips = ArmStrips(model, arm, buoyancy, wet)
    except ValueError as exc:  # a wet geom of a shape it has no member for
        raise ConfigError("simulation.arm_hydrodynamics", f"strips: {exc} ('ellipsoid' takes any)") from exc
    # kept off MuJoCo's fluid model; their fluid shape stays on, so that they do not fall back
    # to its inertia-box drag where the hull keeps MuJoCo's model
    model.geom_fluid[np.isin(model.geom_bodyid, arm) & wet, 1:] = 0.0
    return strips


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
        self._marine_models(config)
        self.marine: Marine | None = None
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

    def _marine_models(self, config: SimulationConfig) -> None:
        """The hull's model (Fossen's or MuJoCo's), the buoyancy, the arm's (the strips or MuJoCo's),
        and MuJoCo's fluid model on where one of them is its."""
        rho = WATER_DENSITY_KGPM3
        self.hydrodynamics: Fossen | None = None
        if config.hydrodynamics == "fossen":  # the marine model replaces the hull's ellipsoids
            self.hydrodynamics = Fossen(self.model, self.vehicle, self.robot.base, rho_kgpm3=rho)
        self.buoyancy = Buoyancy(
            self.model, dry=() if self.hydrodynamics is None else (self.robot.base,), rho_kgpm3=rho
        )
        self.strips: ArmStrips | None = None
        if config.arm_hydrodynamics == "strips":  # the strip model replaces the arm's ellipsoids
            self.strips = _arm_strips(self.model, self.buoyancy, self.robot.base)
        # the strip model applies the arm's buoyancy with its drag, in one pass
        self._buoyancy_apart = self.strips is None or not set(self.buoyancy.bodies) <= set(self.strips.bodies)
        # MuJoCo's fluid model, where it still carries a part: its passive forces and their
        # derivatives cost more than the rest of a physics step, so it is off entirely otherwise
        # (the panel's valves and levers, with no fluid shape, lose its inertia-box drag then: 0.005
        # and 0.02 N m at 2 rad/s, against their friction of 1.5 and 3 N m)
        self._mujoco_fluid = self.hydrodynamics is None or self.strips is None
        if self._mujoco_fluid:
            self.model.opt.density = rho
        else:
            self.model.opt.density = self.model.opt.viscosity = 0.0

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
        """The physics in C where it is built (native.py): the per-step marine terms (alike bit for
        bit), and the dynamic low level where the strip model carries the whole arm (alike to
        rounding); each None where it runs in Python."""
        self.marine = (
            Marine.of(self.data, self.hydrodynamics, self.strips) if self.controller.dynamics else None
        )
        self.native_low_level = (
            LowLevel.of(self.controller, self.strips)
            if self.marine is not None and not self._buoyancy_apart and not self._mujoco_fluid
            else None
        )

    def use_strips(self, strips: ArmStrips) -> None:
        """Another strip model of the arm (other coefficients: tests, benches), C's with it."""
        self.strips = strips
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
        if self.marine is not None:  # the marine terms in C: a low-level period's steps in one call
            for start in range(0, steps, every):
                self._low_level(refs, dt * every)
                self.marine.step(m, self.water_mps_world, min(every, steps - start))
            return
        fossen, strips = self.hydrodynamics, self.strips
        step1, factor, step2 = mujoco.mj_step1, mujoco.mj_factorM, mujoco.mj_step2
        for i in range(steps):
            if i % every == 0:  # the low level runs at its own rate; its outputs hold between
                self._low_level(refs, dt * every)
            if fossen is None and strips is None:  # MuJoCo's fluid model alone: no Python per step
                mujoco.mj_step(m, d)
                continue
            # the added masses go into MuJoCo's inertia between its two halves of a step
            step1(m, d)
            if fossen is not None:
                fossen.apply(m, d, self.water_mps_world, factor=False)
            if strips is not None:
                strips.add_mass(d)
            factor(m, d)
            step2(m, d)

    def _low_level(self, refs: References, period_s: float) -> None:
        """The controllers, the current, and the marine forces held until the next update."""
        d = self.data
        self.current.advance(d.time)
        self.water_mps_world = self.current.velocity_mps_world(d.qpos[self.plant.qpos + 2])
        if self.native_low_level is not None:  # the controllers and the arm's forces, one call
            self.native_low_level.apply(d, refs, self.water_mps_world, period_s)
            return
        self.controller.apply(d, refs, period_s)
        if self._mujoco_fluid:
            self.model.opt.wind[:] = self.water_mps_world  # for MuJoCo's drag
        if self._buoyancy_apart:
            self.buoyancy.apply(d)
        if self.strips is not None:  # after the buoyancy: it sets its links' whole xfrc_applied
            self.strips.apply(d, self.water_mps_world)

    @property
    def physics(self) -> str:
        """Where the physics runs, for summary.json: "c" (the per-step terms and the low level),
        "c-steps" (the per-step terms alone), "python", "kinematic" (no forces); runs replay alike
        only on the same."""
        if not self.controller.dynamics:
            return "kinematic"
        if self.marine is None:
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
