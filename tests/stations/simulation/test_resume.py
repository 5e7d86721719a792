"""A restarted simulation goes on where the vehicle was (World.save_state, World.resume), and a
missing or foreign state file leaves a fresh world as it was."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from abyss.config.simulation import SimulationConfig
from abyss.interface.messages import ArmVelocityRef, VelocityRef
from abyss.stations.simulation.world import World, references

DT_S = 0.01


def world() -> World:
    return World(SimulationConfig(camera_rate_hz=0), np.random.default_rng(0))


@pytest.fixture(scope="module")
def moved(tmp_path_factory: pytest.TempPathFactory) -> tuple[World, Path]:
    """A world driven for 1 s (surge, heave, yaw and the arm), its state saved."""
    w = world()
    refs = references(
        VelocityRef(np.array([0.3, 0.0, -0.1]), 0.2),
        ArmVelocityRef(np.array([0.2, -0.1, 0.1, 0.3, -0.2, 0.3]), 0.0),
    )
    for _ in range(100):
        w.step(refs, DT_S)
    path = tmp_path_factory.mktemp("state") / "state.npy"
    w.save_state(path)
    return w, path


def test_resume_goes_on_from_the_saved_state(moved: tuple[World, Path]) -> None:
    saved, path = moved
    fresh = world()
    start = fresh.truth().position_m_world
    assert np.linalg.norm(saved.truth().position_m_world - start) > 0.05  # it did move
    assert path.exists() and not list(path.parent.glob(".*partial"))
    assert fresh.resume(path)
    then, now = saved.truth(), fresh.truth()
    assert now.sim_time_s == pytest.approx(1.0) and now.sim_time_s == then.sim_time_s
    np.testing.assert_array_equal(now.position_m_world, then.position_m_world)
    np.testing.assert_array_equal(now.orientation_wxyz_world, then.orientation_wxyz_world)
    np.testing.assert_array_equal(now.velocity_mps_body, then.velocity_mps_body)
    np.testing.assert_array_equal(fresh.joints().positions_rad, saved.joints().positions_rad)
    np.testing.assert_array_equal(fresh.joints().velocities_radps, saved.joints().velocities_radps)
    # and it steps on from there
    fresh.step(references(None, None), DT_S)
    assert fresh.truth().sim_time_s == pytest.approx(1.0 + DT_S)


def assert_untouched(w: World, start: np.ndarray, joints: np.ndarray) -> None:
    assert w.truth().sim_time_s == 0.0
    np.testing.assert_array_equal(w.truth().position_m_world, start)
    np.testing.assert_array_equal(w.joints().positions_rad, joints)


def test_resume_from_a_missing_file_changes_nothing(tmp_path: Path) -> None:
    w = world()
    start, joints = w.truth().position_m_world, w.joints().positions_rad
    np.testing.assert_array_equal(start, SimulationConfig().start_position_m_world)
    assert not w.resume(tmp_path / "none.npy")
    assert_untouched(w, start, joints)


def test_resume_from_a_state_of_the_wrong_size_changes_nothing(
    moved: tuple[World, Path], tmp_path: Path
) -> None:
    _, path = moved
    state = np.load(path)
    w = world()
    start, joints = w.truth().position_m_world, w.joints().positions_rad
    for name, wrong in (("short", state[:-1]), ("long", np.r_[state, 0.0]), ("empty", np.zeros(0))):
        bad = tmp_path / f"{name}.npy"
        np.save(bad, wrong)
        assert not w.resume(bad), name
        assert_untouched(w, start, joints)


def test_resume_from_a_file_that_is_no_state_changes_nothing(tmp_path: Path) -> None:
    w = world()
    start, joints = w.truth().position_m_world, w.joints().positions_rad
    bad = tmp_path / "state.npy"
    bad.write_bytes(b"not a numpy file")
    assert not w.resume(bad)
    assert_untouched(w, start, joints)
