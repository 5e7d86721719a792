"""The physics step of a robot in the water, the one place it is written: MuJoCo's step with the
hull's marine model (Fossen's, hydrodynamics.py, or MuJoCo's ellipsoids), the buoyancy of every
other wet body (marine.py) and the arm's model (the strips, strips.py; MuJoCo's ellipsoids; or
none, its buoyancy alone). The simulation's World flies it on its site under its low level; the
robot check's bench (validation/robot/physics.py) flies it on the robot alone, open loop, with the
arm's drag off so that it measures the vehicle's model.

A step has two rates: `forces` at the low level's (the buoyancy, the strips' drag and MuJoCo's
current, held between), `step` the physics steps between; those run in C where native_physics.c
is built (native.Marine: bit for bit the Python's)."""

from __future__ import annotations

import mujoco
import numpy as np

from abyss.common.errors import ConfigError
from abyss.config.simulation import ArmHydrodynamics, Hydrodynamics
from abyss.description.robot import Robot
from abyss.stations.simulation.hydrodynamics import Fossen
from abyss.stations.simulation.marine import WATER_DENSITY_KGPM3, Buoyancy, wet_geoms
from abyss.stations.simulation.native import Marine
from abyss.stations.simulation.strips import ArmStrips


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


class MarinePhysics:
    """`model` and `data` of a robot (its vehicle the body and free joint named `robot.base`) in
    the water; `in_c`: the steps in C where it is built (False: in Python)."""

    def __init__(
        self,
        model: mujoco.MjModel,
        data: mujoco.MjData,
        robot: Robot,
        hydrodynamics: Hydrodynamics,
        arm_hydrodynamics: ArmHydrodynamics,
        in_c: bool = True,
    ) -> None:
        rho = WATER_DENSITY_KGPM3
        self.model, self.data = model, data
        self.fossen: Fossen | None = None
        if hydrodynamics == "fossen":  # the marine model replaces the hull's ellipsoids
            self.fossen = Fossen(model, robot.marine, robot.base, rho_kgpm3=rho)
        self.buoyancy = Buoyancy(model, dry=() if self.fossen is None else (robot.base,), rho_kgpm3=rho)
        self.strips: ArmStrips | None = None
        if arm_hydrodynamics == "strips":  # the strip model replaces the arm's ellipsoids
            self.strips = _arm_strips(model, self.buoyancy, robot.base)
        # MuJoCo's fluid model, where it still carries a part: its passive forces and their
        # derivatives cost more than the rest of a physics step, so it is off entirely otherwise
        # (the panel's valves and levers, with no fluid shape, lose its inertia-box drag then: 0.005
        # and 0.02 N m at 2 rad/s, against their friction of 1.5 and 3 N m)
        self.mujoco_fluid = self.fossen is None or arm_hydrodynamics == "ellipsoid"
        if self.mujoco_fluid:
            model.opt.density = rho
        else:
            model.opt.density = model.opt.viscosity = 0.0
        self.in_c = in_c
        self.marine: Marine | None = None
        self._bind()

    def _bind(self) -> None:
        self.marine = Marine.of(self.data, self.fossen, self.strips) if self.in_c else None

    @property
    def buoyancy_apart(self) -> bool:
        """Whether the buoyancy is applied apart from the strips (which apply their links' with
        their drag, in one pass): some wet body is not one of theirs."""
        return self.strips is None or not set(self.buoyancy.bodies) <= set(self.strips.bodies)

    def use_strips(self, strips: ArmStrips) -> None:
        """Another strip model of the arm (other coefficients: tests, benches), C's with it."""
        self.strips = strips
        self._bind()

    def forces(self, water_mps_world: np.ndarray) -> None:
        """The forces held over the next steps: the buoyancy and the arm's drag in `water_mps_world`
        (the current where the vehicle is [m/s]), MuJoCo's drag in it where its model runs."""
        if self.mujoco_fluid:
            self.model.opt.wind[:] = water_mps_world
        if self.buoyancy_apart:
            self.buoyancy.apply(self.data)
        if self.strips is not None:  # after the buoyancy: it sets its links' whole xfrc_applied
            self.strips.apply(self.data, water_mps_world)

    def step(self, water_mps_world: np.ndarray, steps: int) -> None:
        """`steps` physics steps with the hull's model in `water_mps_world` and the held forces."""
        m, d = self.model, self.data
        if self.marine is not None:  # the marine terms in C: the steps in one call
            self.marine.step(m, water_mps_world, steps)
            return
        fossen, strips = self.fossen, self.strips
        if fossen is None and strips is None:  # MuJoCo's fluid model alone: no Python per step
            mujoco.mj_step(m, d, nstep=steps)
            return
        step1, factor, step2 = mujoco.mj_step1, mujoco.mj_factorM, mujoco.mj_step2
        for _ in range(steps):
            # the added masses go into MuJoCo's inertia between its two halves of a step
            step1(m, d)
            if fossen is not None:
                fossen.apply(m, d, water_mps_world, factor=False)
            if strips is not None:
                strips.add_mass(d)
            factor(m, d)
            step2(m, d)
