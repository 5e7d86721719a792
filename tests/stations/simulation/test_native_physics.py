"""The physics in C (stations/simulation/native.py, native_physics.c as setup.sh builds it): with
the per-step marine terms in C a World steps bit for bit as the Python path does, with a current,
the vehicle turning and the arm moving, over whole and partial low-level periods; the callback acts
on the MjData registered and active alone. The low level in C gives the Python's outputs to
rounding, period by period and over a flight, faults and saturation included, on both shipped
robots: the work-class's six-joint arm, and the BlueROV2's four-joint arm with its attitude hold
(roll and pitch through the same thrusters), which ran in Python before."""

from __future__ import annotations

import dataclasses
import shutil
import subprocess
import sys

import mujoco
import numpy as np
import pytest

from abyss.config import load
from abyss.config.simulation import SimulationConfig
from abyss.description.robot import ROBOTS_DIR, robot_at
from abyss.interface.messages import SimulationControl
from abyss.stations.simulation import native
from abyss.stations.simulation.faults import apply as apply_fault
from abyss.stations.simulation.lowlevel import References
from abyss.stations.simulation.world import World

pytestmark = pytest.mark.skipif(
    shutil.which("cc") is None, reason="no C compiler: setup.sh leaves the marine terms in Python"
)
CONFIG = SimulationConfig(current_profile=((0.0, 0.2, -0.1, 0.0),), current_sigma_mps=0.05)
MOVING = References(np.array([0.3, 0.1, -0.05, 0.2]), np.array([0.2, -0.3, 0.25, 0.1, -0.2, 0.3]), 0.01)
BLUEROV2 = load(  # its package's low-level gains, the attitude hold's among them
    None,
    [f"simulation.robot={ROBOTS_DIR / 'bluerov2_heavy_alpha5'}",
     "simulation.current_profile=[[0.0, 0.2, -0.1, 0.0]]", "simulation.current_sigma_mps=0.05"],
).simulation  # fmt: skip
ROBOTS = {"workclass": CONFIG, "bluerov2": BLUEROV2}


def arm_of(refs: References, config: SimulationConfig) -> References:
    """`refs` with the arm's references cut to the robot's joints."""
    joints = len(robot_at(config.robot).arm_joints)
    return References(refs.vehicle_body, refs.arm_radps[:joints], refs.gripper_mps)


def flown(in_c: bool, config: SimulationConfig = CONFIG) -> World:
    world = World(config, np.random.default_rng(3))
    world.native_low_level = None  # the low level in Python in both: these are the per-step terms
    if not in_c:
        world.physics.marine = None  # the Python path
    for _ in range(30):
        world.step(MOVING, 0.05)  # whole low-level periods (5 steps each)
    world.step(MOVING, 0.012)  # one and a fifth
    return world


def test_setup_built_the_library_and_worlds_step_with_it() -> None:
    assert native.library() is not None, f"{native.LIBRARY} missing: run setup.sh"
    world = World(CONFIG, np.random.default_rng(0))
    assert world.physics.marine is not None and world.native_low_level is not None


@pytest.mark.parametrize("arm", ["strips", "none"])  # none: the robot check's bench's physics
def test_the_marine_terms_in_c_step_bit_for_bit_as_python_does(arm: str) -> None:
    config = dataclasses.replace(CONFIG, arm_hydrodynamics=arm)
    in_c, in_python = flown(True, config), flown(False, config)
    assert (in_c.physics.strips is None) == (arm == "none") and in_c.model.opt.density == 0.0
    assert in_c.data.time == pytest.approx(1.512)
    moved = np.linalg.norm(in_c.data.qpos[:3] - np.asarray(CONFIG.start_position_m_world))
    assert moved > 0.1  # it flew, in a current
    for field in ("qpos", "qvel", "qfrc_applied", "xfrc_applied", "M"):
        assert np.array_equal(getattr(in_c.data, field), getattr(in_python.data, field)), field


def test_the_callback_leaves_other_data_and_other_steps_alone() -> None:
    world = World(CONFIG, np.random.default_rng(0))
    assert world.physics.marine is not None
    other = mujoco.MjData(world.model)  # the same model, not registered
    mujoco.mj_step(world.model, other, nstep=10)
    assert not other.qfrc_applied.any()
    mujoco.mj_forward(world.model, world.data)  # registered, but not stepping: inactive
    assert not world.data.qfrc_applied.any()
    world.step(MOVING, 0.01)
    assert world.data.qfrc_applied.any()  # the hull's terms, in its steps


LOW_LEVEL_OUTPUTS = ("ctrl", "xfrc_applied")


def outputs(world: World) -> dict[str, np.ndarray]:
    """What a low-level period leaves for the steps, and the state it carries to the next."""
    controller = world.controller
    return {
        **{field: getattr(world.data, field).copy() for field in LOW_LEVEL_OUTPUTS},
        "inertia": world.physics.strips.values.copy(),  # type: ignore[union-attr]
        "vehicle_integral": controller.vehicle_integral.copy(),  # type: ignore[attr-defined]
        "vehicle_error": controller.vehicle_error.copy(),  # type: ignore[attr-defined]
        "arm_integral": controller.arm_integral.copy(),  # type: ignore[attr-defined]
        "rotors": controller.thrusters.rotor_speed.copy(),  # type: ignore[attr-defined]
    }


def assert_alike(c: dict[str, np.ndarray], python: dict[str, np.ndarray], rtol: float) -> None:
    for name, value in python.items():
        scale = max(1.0, float(np.abs(value).max()))
        assert np.abs(c[name] - value).max() <= rtol * scale, (name, c[name], value)


@pytest.mark.parametrize(
    "refs",
    [
        MOVING,
        # beyond the thrusters: the allocation scales down, the integral holds (anti-windup)
        References(np.array([3.0, -2.0, 1.0, 2.0]), np.array([3.0, -3.0, 3.0, 3.0, -3.0, 3.0]), -0.05),
    ],
    ids=["moving", "saturated"],
)
@pytest.mark.parametrize("robot", ROBOTS)
def test_the_low_level_in_c_gives_the_pythons_outputs_period_by_period(refs: References, robot: str) -> None:
    """From the same state, each period's controls, the arm's forces and inertia entries and the
    controllers' state alike to rounding; a weakened thruster reaches C through the fault's array."""
    config = ROBOTS[robot]
    refs = arm_of(refs, config)
    world = World(config, np.random.default_rng(3))
    native_low_level = world.native_low_level
    assert native_low_level is not None
    assert bool(world.controller.attitude.held) == (robot == "bluerov2")  # type: ignore[attr-defined]
    for period in range(40):
        if period == 20:
            apply_fault(world, SimulationControl("thruster", "thr_fl", 0.5), set())
        before = outputs(world)
        world.native_low_level = native_low_level
        world._low_level(refs, 0.01)
        in_c = outputs(world)
        restore(world, before)  # the Python's turn from the same state
        world.native_low_level = None
        world._low_level(refs, 0.01)
        assert_alike(in_c, outputs(world), rtol=1e-12)
        world.physics.marine.step(world.model, world.water_mps_world, 5)  # type: ignore[union-attr]
    assert world.controller.thrusters.efficiency.min() == 0.5  # type: ignore[attr-defined]


def restore(world: World, state: dict[str, np.ndarray]) -> None:
    controller = world.controller
    for field in LOW_LEVEL_OUTPUTS:
        getattr(world.data, field)[:] = state[field]
    world.physics.strips.values[:] = state["inertia"]  # type: ignore[union-attr]
    controller.vehicle_integral[:] = state["vehicle_integral"]  # type: ignore[attr-defined]
    controller.vehicle_error[:] = state["vehicle_error"]  # type: ignore[attr-defined]
    controller.arm_integral[:] = state["arm_integral"]  # type: ignore[attr-defined]
    controller.thrusters.rotor_speed[:] = state["rotors"]  # type: ignore[attr-defined]


@pytest.mark.parametrize("robot", ROBOTS)
def test_a_flight_with_the_low_level_in_c_follows_the_pythons_to_rounding(robot: str) -> None:
    """Ten seconds of flight in a current, the arm moving: the two paths part by rounding alone
    (they would part by far more on any changed term: a thruster's efficiency of 0.999 moves the
    vehicle by millimetres)."""
    config = ROBOTS[robot]
    moving = arm_of(MOVING, config)
    in_c, in_python = World(config, np.random.default_rng(3)), World(config, np.random.default_rng(3))
    assert in_c.native_low_level is not None
    in_python.native_low_level = None
    for _ in range(200):
        in_c.step(moving, 0.05)
        in_python.step(moving, 0.05)
    assert np.linalg.norm(in_c.data.qpos[:3] - np.asarray(config.start_position_m_world)) > 1.0
    assert np.abs(in_c.data.qpos - in_python.data.qpos).max() < 1e-9
    assert np.abs(in_c.data.qvel - in_python.data.qvel).max() < 1e-9


def test_a_library_built_from_another_layout_is_refused_and_the_physics_runs_in_python() -> None:
    """The library is a build output beside the source, not part of it: one built from a source
    whose structs were laid out otherwise (bench/cost.py's baseline tree, with this checkout's
    library, crashed its stations) is refused with why, not read with the wrong layout."""
    probe = "import abyss.stations.simulation.native as n; n.ABI += 1; print(n.library())"
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and done.stdout.strip() == "None", done.stderr
    assert "layout" in done.stderr and "run setup.sh" in done.stderr
