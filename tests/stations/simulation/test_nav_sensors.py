"""The simulated navigation sensors in the real world model: USBL fixes at their rate and delay,
the DVL's bottom lock (its altitude range, the panel in its beams, the robot's DVL site), depth
from the pressure."""

from __future__ import annotations

import math

import numpy as np
import pytest

from abyss.config.simulation import SimulationConfig
from abyss.description.robot import ROBOTS_DIR
from abyss.description.site import SITES_DIR
from abyss.interface.messages import NavState, SimulationControl
from abyss.stations.simulation.faults import apply as apply_fault
from abyss.stations.simulation.lowlevel import References
from abyss.stations.simulation.nav_sensors import DVL_M_BODY, SOUND_SPEED_MPS
from abyss.stations.simulation.world import World

pytestmark = pytest.mark.timeout(120)


def world(**settings: object) -> World:
    return World(SimulationConfig(low_level="kinematic", **settings), np.random.default_rng(3))  # type: ignore[arg-type]


def fly(w: World, seconds: float, refs: References | None = None) -> list[NavState]:
    out = []
    for _ in range(round(seconds / w.config.control_period_s)):
        w.step(refs or References.hold(), w.config.control_period_s)
        out.append(w.nav())
    return out


def test_usbl_fixes_come_at_their_rate_each_after_its_travel_and_processing() -> None:
    w = world(
        usbl_rate_hz=1.0, usbl_processing_s=0.3, usbl_dropout_probability=0.0, usbl_outlier_probability=0.0
    )
    navs = fly(w, 30.0, References(np.array([0.0, 0.2, 0.0, 0.0]), np.zeros(6), 0.0))
    delivered = [
        (n.sim_time_s, n.usbl_time_s)
        for i, n in enumerate(navs)
        if n.usbl_time_s >= 0 and (i == 0 or n.usbl_time_s != navs[i - 1].usbl_time_s)
    ]
    measured_s = np.array([m for _, m in delivered])
    assert len(delivered) >= 28
    np.testing.assert_allclose(np.diff(measured_s), 1.0, atol=1e-6)
    slant_m = np.linalg.norm(w.truth().position_m_world)  # the transceiver sits above the origin
    delay_s = np.array([d - m for d, m in delivered])
    assert np.all(delay_s >= 0.3 + 0.9 * slant_m / SOUND_SPEED_MPS)
    assert np.all(delay_s <= 0.3 + 1.1 * slant_m / SOUND_SPEED_MPS + w.config.control_period_s + 1e-9)


def test_usbl_dropouts_and_outliers_come_as_often_as_configured() -> None:
    w = world(usbl_dropout_probability=0.3, usbl_outlier_probability=0.2, usbl_outlier_m=3.0)
    navs = fly(w, 200.0)
    truth = w.truth().position_m_world
    fixes = {n.usbl_time_s: n.position_m_world for n in navs if n.usbl_time_s >= 0}
    assert 0.6 * 200 < len(fixes) < 0.8 * 200
    off = [np.linalg.norm(p[:2] - truth[:2]) for p in fixes.values()]
    outliers = sum(o > 1.0 for o in off)
    assert 0.1 * len(fixes) < outliers < 0.3 * len(fixes)
    assert all(o < 0.2 or 2.5 < o < 3.5 for o in off)


def test_dvl_loses_lock_above_its_altitude_range() -> None:
    at_start_m = 2.35  # the seabed under the DVL at the start
    assert all(n.dvl_valid for n in fly(world(dvl_max_altitude_m=at_start_m + 0.5), 1.0))
    lost = fly(world(dvl_max_altitude_m=at_start_m - 0.5), 1.0)
    assert not any(n.dvl_valid for n in lost) and all(np.all(n.velocity_mps_body == 0.0) for n in lost)


def test_dvl_loses_lock_when_its_beams_meet_the_panel() -> None:
    # sideways on to the panel, its beams on that side fall on the plate 0.75 m off
    near = world(start_position_m_world=(4.2, 0.0, -6.5), start_yaw_rad=math.pi / 2)
    assert np.isnan(near.dvl.altitudes_m(near.data)).sum() == 2
    assert not any(n.dvl_valid for n in fly(near, 1.0))
    clear = world(start_position_m_world=(2.0, 0.0, -6.5), start_yaw_rad=math.pi / 2)
    assert all(n.dvl_valid for n in fly(clear, 1.0))


def test_the_dvl_casts_its_beams_from_the_robots_dvl_site() -> None:
    """The BlueROV2's DVL (its site under the stern, 0.19 m below the hull's centre) locks 0.6 m
    over the seabed, where beams cast from under the work-class's skid (0.7 m down, for a model
    with no DVL site) would start 0.1 m over it, under the 0.3 m it needs."""
    small = world(
        robot=str(ROBOTS_DIR / "bluerov2_heavy_alpha5"),
        site=str(SITES_DIR / "small_panel"),
        start_position_m_world=(2.0, 0.0, -9.2),  # the seabed at z = -10.0
    )
    np.testing.assert_allclose(small.dvl.origin_m_body, small.model.site(small.robot.nav_sensors.dvl).pos)
    np.testing.assert_allclose(small.dvl.altitudes_m(small.data), 0.6, atol=0.03)  # the terrain undulates
    assert all(n.dvl_valid for n in fly(small, 1.0))
    np.testing.assert_array_equal(world().dvl.origin_m_body, DVL_M_BODY)


def test_depth_comes_from_the_pressure_and_its_noise_fault() -> None:
    w = world(pressure_sigma_pa=100.0)
    depth_m = -w.truth().position_m_world[2]
    nominal = [n.depth_m - depth_m for n in fly(w, 50.0)]
    apply_fault(w, SimulationControl("noise", "depth", 10.0), set())
    raised = [n.depth_m - depth_m for n in fly(w, 50.0)]
    assert np.std(nominal) == pytest.approx(100.0 / (1025 * 9.81), rel=0.1)
    assert np.std(raised) == pytest.approx(1000.0 / (1025 * 9.81), rel=0.1)
    assert abs(np.mean(nominal)) < 0.002
