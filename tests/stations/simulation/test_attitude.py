"""The dynamic low level's attitude hold (stations/simulation/attitude.py) on the BlueROV2 Heavy: its
four vertical thrusters bring a tilted vehicle back level within seconds; without the gains the
tilt is left to its hydrostatic restoring moment (1.7 N m/rad), which rocks it for longer."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from abyss.common.geometry import quat_wxyz_of, rotation_of_rpy
from abyss.config.simulation import SimulationConfig
from abyss.description.robot import ROBOTS_DIR
from abyss.description.site import SITES_DIR
from abyss.stations.simulation.attitude import PITCH, ROLL
from abyss.stations.simulation.lowlevel import References
from abyss.stations.simulation.world import World

pytestmark = pytest.mark.timeout(120)
PERIOD_S = 0.05
TILT_RAD = (0.3, 0.2)  # roll, pitch at the start


def tilted(**settings: object) -> World:
    """The BlueROV2 in open water 1 m over the small panel's seabed, rolled and pitched."""
    world = World(
        SimulationConfig(
            robot=str(ROBOTS_DIR / "bluerov2_heavy_alpha5"),
            site=str(SITES_DIR / "small_panel"),
            start_position_m_world=(1.5, 0.0, -8.5),
            **settings,  # type: ignore[arg-type]
        ),
        np.random.default_rng(0),
    )
    qpos = world.plant.qpos
    world.data.qpos[qpos + 3 : qpos + 7] = quat_wxyz_of(rotation_of_rpy(*TILT_RAD, 0.0))
    mujoco.mj_forward(world.model, world.data)
    return world


def roll_pitch_rad(world: World) -> np.ndarray:
    rotation = world.plant.rotation(world.data)
    return np.array([math.atan2(rotation[2, 1], rotation[2, 2]), -math.asin(rotation[2, 0])])


def tilts_rad(world: World, seconds: float) -> np.ndarray:
    """|roll| and |pitch| after each control period, still."""
    seen = []
    for _ in range(round(seconds / PERIOD_S)):
        world.step(References.hold(), PERIOD_S)
        seen.append(np.abs(roll_pitch_rad(world)))
    return np.array(seen)


def test_the_vertical_thrusters_hold_roll_and_pitch_level_where_the_gains_ask() -> None:
    held = tilted(attitude_kp=(12.5, 12.5), attitude_kd=(3.5, 3.5))
    free = tilted()
    assert held.controller.attitude.held == (ROLL, PITCH) and free.controller.attitude.held == ()
    assert held.runs_in == "c"  # the attitude hold in C with the rest of the low level
    np.testing.assert_allclose(roll_pitch_rad(held), TILT_RAD, atol=1e-9)
    held_rad, free_rad = tilts_rad(held, 6.0), tilts_rad(free, 6.0)
    late = slice(round(3.0 / PERIOD_S), None)  # from 3 s on
    assert held_rad[late].max() < 0.005, held_rad[late].max()  # level within 3 s (measured 0.001 rad)
    assert free_rad[late].max() > 0.05, free_rad[late].max()  # still rolling 0.1 rad on its own (measured)
