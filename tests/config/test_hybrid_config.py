"""A hybrid run's configuration: every output of the simulation has one provider, or the run is
refused at start naming them; the site's registration; `abyss keys` says who provides what."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest

from abyss.common.errors import ConfigError
from abyss.common.geometry import quat_multiply
from abyss.config import load
from abyss.config.hybrid import OUTPUTS, HybridConfig


def test_the_twin_renders_what_the_vehicle_does_not_provide() -> None:
    assert HybridConfig().providers() == {t: "simulation" for t in OUTPUTS}
    providers = HybridConfig(vehicle=("nav", "joints", "sonar")).providers()
    assert providers == {
        "nav": "vehicle",
        "joints": "vehicle",
        "sonar": "vehicle",
        "camera/left": "twin",
        "camera/right": "twin",
        "camera/depth": "twin",
    }


@pytest.mark.parametrize(
    ("vehicle", "twin", "field", "says"),
    [
        (("nav", "joints", "sonar"), ("sonar",), "hybrid.twin", "sonar: two providers, the real vehicle"),
        (("nav",), (), "hybrid.vehicle", "joints: no provider"),
        (
            ("nav", "joints"),
            ("camera/left",),
            "hybrid.vehicle",
            "camera/right, camera/depth, sonar: no provider",
        ),
        (("nav", "joints", "camera/left"), ("joints",), "hybrid.twin", "joints: two providers"),
        (("joints", "camera/left"), ("nav",), "hybrid.twin", "nav: the twin runs no dynamics"),
        (("nav", "joints", "gps"), (), "hybrid.vehicle", "'gps' is not an output of the simulation"),
        ((), ("camera/left",), "hybrid.twin", "a twin needs a real vehicle"),
    ],
)
def test_a_key_with_two_providers_or_none_is_refused_naming_them(
    vehicle: tuple[str, ...], twin: tuple[str, ...], field: str, says: str
) -> None:
    with pytest.raises(ConfigError) as refused:
        HybridConfig(vehicle=vehicle, twin=twin)
    assert refused.value.field == field and says in refused.value.reason, refused.value


def test_a_real_vehicle_runs_on_the_wall_clock_and_a_ros2_one_provides_navigation_and_joints() -> None:
    with pytest.raises(ConfigError, match="runs on the wall clock"):
        load(overrides=['hybrid.vehicle=["nav", "joints"]', "time.mode=lockstep"])
    with pytest.raises(ConfigError, match="provides nav, joints at most"):
        load(overrides=['hybrid.vehicle=["nav", "joints", "sonar"]', "ros2.station=simulation"])
    assert load(overrides=['hybrid.vehicle=["nav", "joints"]', "ros2.station=simulation"]).hybrid.on


def test_the_registration_takes_the_site_origin_and_heading_off_a_pose_in_the_navigation_frame() -> None:
    heading = math.radians(30.0)
    hybrid = HybridConfig(
        vehicle=("nav", "joints"), site_origin_m_nav=(100.0, -50.0, -2.0), site_heading_rad=heading
    )
    # 2 m along the site's x axis, facing along it, rolled a little: as the vehicle's navigation sees it
    along = np.array([math.cos(heading), math.sin(heading), 0.0])
    roll = np.array([math.cos(0.05), math.sin(0.05), 0.0, 0.0])
    seen = quat_multiply(np.array([math.cos(heading / 2), 0.0, 0.0, math.sin(heading / 2)]), roll)
    position, orientation = hybrid.site_pose(
        np.array([100.0, -50.0, -2.0]) + 2.0 * along + [0, 0, -5.0], seen
    )
    np.testing.assert_allclose(position, [2.0, 0.0, -5.0], atol=1e-12)
    np.testing.assert_allclose(orientation, roll, atol=1e-12)


def test_the_registration_puts_a_pose_in_the_site_frame_into_the_navigation_frame_site_poses_inverse() -> (
    None
):
    heading = math.radians(40.0)
    hybrid = HybridConfig(
        vehicle=("nav", "joints"), site_origin_m_nav=(30.0, -12.0, 0.0), site_heading_rad=heading
    )
    # the site's origin, facing along its x axis: the registration's origin, turned by its heading
    position, orientation = hybrid.nav_pose(np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0]))
    np.testing.assert_allclose(position, [30.0, -12.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(
        orientation, [math.cos(heading / 2), 0.0, 0.0, math.sin(heading / 2)], atol=1e-12
    )
    # 2 m along the site's x axis lies 2 m along the heading in the navigation frame
    position, _ = hybrid.nav_pose(np.array([2.0, 0.0, -5.0]), np.array([1.0, 0.0, 0.0, 0.0]))
    np.testing.assert_allclose(position, [30.0 + 2 * math.cos(heading), -12.0 + 2 * math.sin(heading), -5.0])
    rng = np.random.default_rng(7)
    for _ in range(20):  # each undoes the other, both ways round
        p = rng.uniform(-50.0, 50.0, 3)
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        for there, back in ((hybrid.nav_pose, hybrid.site_pose), (hybrid.site_pose, hybrid.nav_pose)):
            p2, q2 = back(*there(p, q))
            np.testing.assert_allclose(p2, p, atol=1e-9)
            np.testing.assert_allclose(q2, q, atol=1e-12)


def test_with_no_registration_or_no_real_vehicle_the_site_frame_is_the_navigation_frame_untouched() -> None:
    p, q = np.array([5.0, 0.1, -8.6]), np.array([0.9, 0.1, 0.3, 0.3])
    registered = {"site_origin_m_nav": (30.0, -12.0, 0.0), "site_heading_rad": 0.7}
    for hybrid in (HybridConfig(), HybridConfig(vehicle=("nav", "joints")), HybridConfig(**registered)):
        position, orientation = hybrid.nav_pose(p, q)
        assert position is p and orientation is q  # not a float operation on them: bit for bit


def test_abyss_keys_says_who_provides_each_key_in_a_hybrid_run() -> None:
    def keys_table(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [sys.executable, "-P", "-m", "abyss.cli", "keys", *args],
            capture_output=True,
            text=True,
            timeout=60,
        )

    table = keys_table("--hybrid", "nav,joints,sonar").stdout
    rows = {line.split("|")[1].strip(" `"): line.split("|")[-2].strip() for line in table.splitlines()[2:]}
    assert rows["abyss/<system>/simulation/nav"] == "the real vehicle"
    assert rows["abyss/<system>/simulation/sonar"] == "the real vehicle"
    assert rows["abyss/<system>/simulation/camera/depth"] == "the twin (simulation)"
    assert rows["abyss/<system>/onboard/cmd/vehicle_velocity"] == "onboard"
    refused = keys_table("--hybrid", "nav,joints", "--set", 'hybrid.twin=["camera/left", "joints"]')
    assert refused.returncode == 2 and "joints: two providers, the real vehicle" in refused.stderr, (
        refused.stderr
    )
