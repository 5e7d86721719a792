"""The site as data (description/site.py): a site package loads, composes with any robot package, its
panel is built from its site.toml, a bad one is refused at load naming the file and the field;
the robot's and the site's [config] lie under the user's configuration."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from abyss.common.errors import ConfigError
from abyss.config import load
from abyss.description.robot import SHIPPED_ROBOT_DIR, robot_at
from abyss.description.site import SHIPPED_SITE_DIR, load_site, site_at, world_model

ONE_VALVE_ONE_LEVER = """
[[panel.parts]]
name = "gate"
kind = "valve"
pivot_m_panel = [-0.07, 0.2, 0.1]

[[panel.parts]]
name = "throttle"
kind = "lever"
pivot_m_panel = [-0.07, -0.2, -0.1]
"""


def _site(tmp_path: Path, name: str = "site", parts: str = ONE_VALVE_ONE_LEVER, extra: str = "") -> Path:
    """The shipped site copied with its parts replaced by `parts`, and `extra` appended."""
    package = tmp_path / name
    shutil.copytree(SHIPPED_SITE_DIR, package)
    text = (package / "site.toml").read_text()
    text = text[: text.index("[[panel.parts]]")] + parts + extra
    (package / "site.toml").write_text(text)
    return package


def test_a_site_of_its_own_builds_its_parts_and_composes_with_the_robot(tmp_path: Path) -> None:
    site = load_site(_site(tmp_path))
    world = world_model(robot_at(""), site)
    assert site.panel.valves == {"gate": (-0.07, 0.2, 0.1)} and site.panel.levers == {
        "throttle": (-0.07, -0.2, -0.1)
    }
    assert world.body(1).name == robot_at("").base  # the robot first, whatever the site
    for name, kind in (("gate", site.panel.valve), ("throttle", site.panel.lever)):
        assert np.allclose(world.jnt_range[world.joint(name).id], np.radians(kind.range_deg))
        assert np.allclose(world.jnt_axis[world.joint(name).id], kind.axis_panel)
        assert world.dof_frictionloss[world.joint(name).dofadr[0]] == kind.friction_n_m
    with pytest.raises(KeyError, match="valve_0"):
        world.joint("valve_0")  # the shipped panel's parts are not there
    assert site.panel.intent("throttle", "up") == (0.0, "up")


@pytest.mark.parametrize(
    ("parts", "extra", "field", "allowed"),
    [
        (ONE_VALVE_ONE_LEVER.replace('"throttle"', '"gate"'), "", "panel.parts", "named twice: gate"),
        (
            ONE_VALVE_ONE_LEVER.replace('kind = "lever"', 'kind = "knob"'),
            "",
            "panel.parts[1].kind",
            "valve, lever",
        ),
        (
            ONE_VALVE_ONE_LEVER,
            "[colour]\nx = 1\n",
            "colour",
            "allowed: config, datum, model, name, panel, source",
        ),
    ],
)
def test_a_bad_site_is_refused_naming_the_file_and_the_field(
    tmp_path: Path, parts: str, extra: str, field: str, allowed: str
) -> None:
    package = _site(tmp_path, parts=parts, extra=extra)
    with pytest.raises(ConfigError, match=rf"site\.toml: {re.escape(field)}: .*{allowed}"):
        load_site(package)


def test_a_missing_texture_and_model_are_named(tmp_path: Path) -> None:
    package = _site(tmp_path, "no-texture")
    (package / "panel_face.png").unlink()
    with pytest.raises(ConfigError, match=r"site\.toml: panel\.face_texture: no such file"):
        load_site(package)
    package = _site(tmp_path, "no-model")
    (package / "site.xml").unlink()
    with pytest.raises(ConfigError, match=r"site\.toml: model\.file: no such file"):
        load_site(package)


def test_the_packages_configuration_lies_under_the_users(tmp_path: Path) -> None:
    """The robot's [config], then the site's (the robot's may name its site), then the user's on
    top; a mission naming a part the site lacks is refused naming the field."""
    site = _site(tmp_path, extra='\n[config]\n"mission" = { interventions = [["gate", "45"]] }\n')
    robot = tmp_path / "robot"
    shutil.copytree(SHIPPED_ROBOT_DIR, robot)
    with (robot / "robot.toml").open("a") as toml:  # beside the workclass's [config.simulation]
        toml.write(f'site = "{site}"\narm_kp = 123.0\n\n[config.mission]\nwaypoint_timeout_s = 7.0\n')
    config = load(None, [f"simulation.robot={robot}", "mission.waypoint_timeout_s=9"])
    assert config.simulation.site == str(site.resolve()) and config.simulation.arm_kp == 123.0
    assert config.mission.interventions == (("gate", "45"),) and config.mission.waypoint_timeout_s == 9.0
    with pytest.raises(
        ConfigError, match=r"mission\.interventions\[0\]: 'valve_1' is not a part of the panel: gate"
    ):
        load(None, [f"simulation.site={site}", 'mission.interventions=[["valve_1", "90"]]'])


def test_a_packages_bad_configuration_names_the_package(tmp_path: Path) -> None:
    site = _site(tmp_path, extra='\n[config]\n"mission" = { interventions = [["valve_1", "90"]] }\n')
    with pytest.raises(
        ConfigError, match=rf"{site}/site\.toml: config: mission\.interventions\[0\]: 'valve_1'"
    ):
        load(None, [f"simulation.site={site}"])


def test_a_shipped_package_is_named_by_its_name() -> None:
    config = load(None, ["simulation.robot=bluerov2_heavy_alpha5", "simulation.site=valve_panel"])
    assert Path(config.simulation.robot).name == "bluerov2_heavy_alpha5"
    assert site_at(config.simulation.site).shipped
    with pytest.raises(ConfigError, match=r"simulation\.site: .*nor a shipped one's name: .*valve_panel"):
        load(None, ["simulation.site=harbour"])
