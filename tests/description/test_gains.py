"""A robot's velocity loops where its package states none (description/gains.py): derived from its
masses and its rotors' lag as the work-class ROV's were tuned, layered under its own [config]."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from abyss.config import load
from abyss.description.gains import derived_gains
from abyss.description.robot import SHIPPED_ROBOT_DIR, robot_at


def test_the_tuned_work_class_loops_are_what_its_masses_derive() -> None:
    derived = derived_gains(robot_at(""))["simulation"]
    tuned = load(None, []).simulation
    np.testing.assert_allclose(derived["vehicle_kp"], tuned.vehicle_kp, rtol=0.01)
    np.testing.assert_allclose(derived["vehicle_ki"], tuned.vehicle_ki, rtol=0.01)


def test_the_bluerov2s_stated_loops_are_near_what_its_masses_derive() -> None:
    """Its robot.toml works its gains through by hand (the arm's yaw inertia counted, which the
    derivation leaves out): within a fifth of the derived."""
    derived = derived_gains(robot_at("bluerov2_heavy_alpha5"))["simulation"]
    stated = load(None, ["simulation.robot=bluerov2_heavy_alpha5"]).simulation
    np.testing.assert_allclose(stated.vehicle_kp, derived["vehicle_kp"], rtol=0.25)
    assert stated.vehicle_kp[:3] == (65.0, 56.0, 85.0)  # its own, over the derived


def test_a_package_stating_none_flies_the_derived_and_a_stated_one_wins(tmp_path: Path) -> None:
    package = tmp_path / "heavier"
    shutil.copytree(SHIPPED_ROBOT_DIR, package)
    toml = package / "robot.toml"
    text = toml.read_text()
    toml.write_text(text[: text.index("\n# The configuration for flying this robot")] + "\n")
    xml = package / "robot.xml"
    xml.write_text(xml.read_text().replace('mass="2989"', 'mass="5978"', 1))  # twice the ballast
    config = load(None, [f"simulation.robot={package}"])
    assert config.simulation.vehicle_kp[0] > 1.7 * 6000.0  # the heavier vehicle's loops are stiffer
    assert config.simulation.vehicle_kp == tuple(
        derived_gains(robot_at(str(package)))["simulation"]["vehicle_kp"]
    )
    stated = load(None, [f"simulation.robot={package}", "simulation.vehicle_kp=[1, 2, 3, 4]"])
    assert stated.simulation.vehicle_kp == (1.0, 2.0, 3.0, 4.0)
