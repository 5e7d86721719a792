from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from abyss.common.errors import ConfigError
from abyss.config import load
from abyss.config.linkprofile import load_profiles, profile
from abyss.interface import keys

ROOT = Path(__file__).resolve().parents[2]


def test_docs_keys_table_is_the_generated_one() -> None:
    page = (ROOT / "docs" / "links.md").read_text()
    assert keys.keys_table() in page


def test_abyss_keys_prints_the_table() -> None:
    out = subprocess.run(
        [sys.executable, "-m", "abyss.cli", "keys"], capture_output=True, text=True, check=True, cwd=ROOT
    ).stdout
    assert out.strip() == keys.keys_table()


def test_every_key_goes_to_a_neighbour_and_types_exist() -> None:
    from abyss.interface.messages import MESSAGES

    for spec in keys.KEYS:
        assert spec.hop in keys.HOPS and spec.message in MESSAGES
    assert keys.key("s1", "onboard", "telemetry") == "abyss/s1/onboard/telemetry"


@pytest.mark.parametrize(
    ("override", "field"),
    [
        ("simulation.control_period_s=0.003", "simulation.control_period_s"),
        ("links.tether=nope", "links.tether"),
        ("onboard.kp=1", "onboard.kp"),
        ("seed=abc", "seed"),
        ("system=bad id!", "system"),
        ("mission.waypoints=[[1,2]]", "mission.waypoints[0]"),
        ('onboard.cloud_sources=["lidar"]', "onboard.cloud_sources"),
        ("onboard.stereo_disparities=60", "onboard.stereo_disparities"),
        ("vessel.scene_share=1.5", "vessel.scene_share"),
        ("vessel.octree_resolution_m=0.001", "vessel.octree_resolution_m"),
        ("vessel.recognition_bias_m=[0, 0, 2]", "vessel.recognition_bias_m"),
        ("vessel.recognition_bias_m=[0, 0]", "vessel.recognition_bias_m"),
        ("ros2.station=simulation", "hybrid.vehicle"),  # a ROS 2 vehicle: a hybrid run says what it gives
        ("ros2.station=shore", "ros2.station"),
        ("ros2.domain=233", "ros2.domain"),
        ("ros2.namespace=abyss", "ros2.namespace"),
        ("ros2.listen=[]", "ros2.listen"),
        # the marine model is the robot package's alone (description/marine.py): no file beside it
        ("simulation.vehicle_file=mine.toml", "simulation.vehicle_file"),
        # bulk work's latency on simulated time: a result out before the next input is taken
        ("simulation.sensor_latency_s=0.5", "simulation.sensor_latency_s"),  # the sonar at 2 Hz
        ("simulation.sensor_latency_s=-0.1", "simulation.sensor_latency_s"),
        ("onboard.perception_latency_s=1.0", "onboard.perception_latency_s"),  # the cameras at 1 Hz
        ("vessel.insertion_latency_s=-1", "vessel.insertion_latency_s"),
    ],
)
def test_bad_config_names_the_field(override: str, field: str) -> None:
    with pytest.raises(ConfigError) as info:
        load(overrides=[override])
    assert info.value.field == field


def test_a_bound_says_whether_zero_is_allowed() -> None:
    with pytest.raises(ConfigError, match=r"-1\.0 must be zero or a positive number"):
        load(overrides=["vessel.scene_track_period_s=-1"])
    with pytest.raises(ConfigError, match=r"0\.0 must be a positive number"):
        load(overrides=["onboard.kp_position=0"])


def test_config_file_error_names_the_file(tmp_path: Path) -> None:
    path = tmp_path / "c.toml"
    path.write_text("[vessel]\ntelemetry_period_s = -1\n")
    with pytest.raises(ConfigError, match=str(path)):
        load(path)


def test_profiles_parse_with_units_and_refuse_bad_values() -> None:
    profiles = load_profiles()
    assert {"ideal", "tether", "satellite", "satellite-storm", "tether-degraded", "outage"} <= set(profiles)
    sat = profiles["satellite"]
    assert (sat.rate_bps, sat.delay_s, sat.jitter_s, sat.loss, sat.corrupt) == (1e6, 0.15, 0.075, 0.05, 0.001)
    assert profiles["tether"].with_fields(profiles["tether"].fields()) == profiles["tether"]
    for fields, match in [
        ({"rate": "20mbits"}, "not a rate"),
        ({"loss": "120%"}, r"\[0%, 100%\]"),
        ({"delay": 5}, "no unit"),
        ({"transport": "sctp"}, "tcp, udp"),
        ({"warp": "1"}, "warp: unknown field; allowed: .*rate"),
    ]:
        with pytest.raises(ConfigError, match=match):
            profile("tether", fields)
    with pytest.raises(ConfigError, match="available: ideal"):
        profile("nope")


def test_cli_refuses_a_bad_profile_before_starting() -> None:
    done = subprocess.run(
        [sys.executable, "-m", "abyss.cli", "up", "--profile", "tether=nope"],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=60,
    )
    assert done.returncode == 2 and "links.tether" in done.stderr and "satellite" in done.stderr
