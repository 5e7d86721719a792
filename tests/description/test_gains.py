"""A robot's velocity loops (description/gains.py): those its package states, else derived from its
masses and its rotors' lag as the work-class ROV's were tuned; the configuration's own instead
where a user sets them."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from abyss.config import load
from abyss.description.gains import derived_gains, robot_gains
from abyss.description.robot import SHIPPED_ROBOT_DIR, robot_at
from abyss.stations.simulation.world import World


def test_the_tuned_work_class_loops_are_what_its_masses_derive() -> None:
    derived_kp, derived_ki = derived_gains(robot_at(""))
    tuned_kp, tuned_ki = robot_gains(robot_at(""))
    assert tuned_kp == (6000.0, 6000.0, 6000.0, 5000.0)  # its package's, not the derived
    np.testing.assert_allclose(derived_kp, tuned_kp, rtol=0.01)
    np.testing.assert_allclose(derived_ki, tuned_ki, rtol=0.01)
    assert load(None, []).simulation.vehicle_kp == ()  # the configuration holds no robot's gains


def test_the_bluerov2s_stated_loops_are_near_what_its_masses_derive() -> None:
    """Its robot.toml works its gains through by hand (the arm's yaw inertia counted, which the
    derivation leaves out): within a fifth of the derived."""
    derived_kp, _ = derived_gains(robot_at("bluerov2_heavy_alpha5"))
    stated_kp, _ = robot_gains(robot_at("bluerov2_heavy_alpha5"))
    np.testing.assert_allclose(stated_kp, derived_kp, rtol=0.25)
    assert stated_kp[:3] == (65.0, 56.0, 85.0)  # its own, over the derived


def test_a_package_stating_none_flies_the_derived_and_a_stated_one_wins(tmp_path: Path) -> None:
    package = tmp_path / "heavier"
    shutil.copytree(SHIPPED_ROBOT_DIR, package)
    toml = package / "robot.toml"
    text = toml.read_text()
    toml.write_text(text[: text.index("\n# The configuration for flying this robot")] + "\n")
    xml = package / "robot.xml"
    xml.write_text(xml.read_text().replace('mass="2989"', 'mass="5978"', 1))  # twice the ballast
    config = load(None, [f"simulation.robot={package}"])
    flown = World(config.simulation, np.random.default_rng(0)).gains
    assert flown.vehicle_kp[0] > 1.7 * 6000.0  # the heavier vehicle's loops are stiffer
    assert flown.vehicle_kp == derived_gains(robot_at(str(package)))[0]
    stated = load(None, [f"simulation.robot={package}", "simulation.vehicle_kp=[1, 2, 3, 4]"])
    assert World(stated.simulation, np.random.default_rng(0)).gains.vehicle_kp == (1.0, 2.0, 3.0, 4.0)
