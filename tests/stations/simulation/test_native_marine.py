"""The physics step's marine terms in C (stations/simulation/native.py, native_marine.c as
setup.sh builds it): a World steps bit for bit as the Python path does, with a current, the
vehicle turning and the arm moving, over whole and partial low-level periods; the callback acts on
the MjData registered and active alone."""

from __future__ import annotations

import shutil

import mujoco
import numpy as np
import pytest

from abyss.common.config.simulation import SimulationConfig
from abyss.stations.simulation import native
from abyss.stations.simulation.lowlevel import References
from abyss.stations.simulation.world import World

pytestmark = pytest.mark.skipif(
    shutil.which("cc") is None, reason="no C compiler: setup.sh leaves the marine terms in Python"
)
CONFIG = SimulationConfig(current_profile=((0.0, 0.2, -0.1, 0.0),), current_sigma_mps=0.05)
MOVING = References(np.array([0.3, 0.1, -0.05, 0.2]), np.array([0.2, -0.3, 0.25, 0.1, -0.2, 0.3]), 0.01)


def flown(in_c: bool) -> World:
    world = World(CONFIG, np.random.default_rng(3))
    if not in_c:
        world.marine = None  # the Python path
    for _ in range(30):
        world.step(MOVING, 0.05)  # whole low-level periods (5 steps each)
    world.step(MOVING, 0.012)  # one and a fifth
    return world


def test_setup_built_the_library_and_worlds_step_with_it() -> None:
    assert native.library() is not None, f"{native.LIBRARY} missing: run setup.sh"
    assert World(CONFIG, np.random.default_rng(0)).marine is not None


def test_the_marine_terms_in_c_step_bit_for_bit_as_python_does() -> None:
    in_c, in_python = flown(True), flown(False)
    assert in_c.data.time == pytest.approx(1.512)
    moved = np.linalg.norm(in_c.data.qpos[:3] - np.asarray(CONFIG.start_position_m_world))
    assert moved > 0.1  # it flew, in a current
    for field in ("qpos", "qvel", "qfrc_applied", "xfrc_applied", "M"):
        assert np.array_equal(getattr(in_c.data, field), getattr(in_python.data, field)), field


def test_the_callback_leaves_other_data_and_other_steps_alone() -> None:
    world = World(CONFIG, np.random.default_rng(0))
    assert world.marine is not None
    other = mujoco.MjData(world.model)  # the same model, not registered
    mujoco.mj_step(world.model, other, nstep=10)
    assert not other.qfrc_applied.any()
    mujoco.mj_forward(world.model, world.data)  # registered, but not stepping: inactive
    assert not world.data.qfrc_applied.any()
    world.step(MOVING, 0.01)
    assert world.data.qfrc_applied.any()  # the hull's terms, in its steps
