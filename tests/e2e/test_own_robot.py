"""A team's own robot and site through the whole system: a robot package written here in URDF
with xacro (tests/description/urdf_package.py: "minirov", whose joints, thrusters, cameras and sites all
differ from the shipped robot's), on a site whose parts differ from the shipped panel's, flies three
waypoints in lockstep; its recording exports to ROS 2 topics that name its joints and its
frames, and the panel it recognised names the site's parts. Any name of the shipped packages still
wired into a station fails here."""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import pytest
from conftest import Up, abyss
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from abyss.description.site import SHIPPED_SITE_DIR

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "description"))
from urdf_package import write_urdf_package

pytestmark = pytest.mark.timeout(300)


def _site(root: Path) -> Path:
    """The shipped site with its parts renamed: a valve "gate" and a lever "throttle"."""
    site = root / "harbour_site"
    shutil.copytree(SHIPPED_SITE_DIR, site)
    text = (site / "site.toml").read_text()
    parts = "".join(
        f'\n[[panel.parts]]\nname = "{name}"\nkind = "{kind}"\npivot_m_panel = {pivot}\n'
        for name, kind, pivot in (
            ("gate", "valve", [-0.07, 0.0, 0.25]),
            ("throttle", "lever", [-0.07, 0.3, -0.3]),
        )
    )
    (site / "site.toml").write_text(text[: text.index("[[panel.parts]]")] + parts)
    return site


def test_a_urdf_robot_of_its_own_flies_its_waypoints_and_exports_its_names(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    package = write_urdf_package(tmp_path)
    monkeypatch.setenv("ABYSS_PACKAGE_PATH", package.package_path)  # every station's, as ROS's would be
    site = _site(tmp_path)
    up = Up(
        tmp_path / "run",
        "--robot", str(package.directory), "--site", str(site),
        "--time", "lockstep", "--duration", "40", "--keep-running", "--record", "all",
        "--viewer", "none",
        "--set", "mission.interventions=[]",
    )  # fmt: skip
    assert up.wait(280) == 0, up.output()
    summary = up.summary()
    # run on past the mission's end (done at 13 s on its derived loops) to a fixed 40 simulated
    # seconds, so that the vessel's recognition is judged at the same time whenever the mission
    # ends, in lockstep: the recognition's pace is the period's, never the machine's load
    assert summary["verdict"] in ("done", "incomplete") and summary["failure"] == "", up.output()[-3000:]
    mission = summary["mission"]
    assert mission["done"] and mission["waypoints_total"] == 3 and mission["waypoint_index"] == 3, mission
    config = json.loads((tmp_path / "run" / "config.json").read_text())
    assert Path(config["simulation"]["robot"]) == package.directory.resolve()
    robot = summary["robot"]  # the package and the names the stations learnt from it
    assert Path(robot["package"]) == package.directory.resolve() and robot["sonar"] == "fls"
    assert robot["arm_joints"] == list(package.arm_joints) and robot["cameras"] == list(package.cameras)
    assert summary["stations"]["simulation"]["sent"].get(f"abyss/{summary['system']}/simulation/sonar", 0) > 0
    assert {"panel", "gate", "throttle"} <= set(
        summary["scene"]["objects"]
    )  # recognised, by its parts' names
    exported = abyss("export", "mcap", str(tmp_path / "run"), timeout_s=120)
    assert exported.returncode == 0, exported.stderr
    names, frames = set(), set()
    with next((tmp_path / "run").glob("*.mcap")).open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _, channel, _, message in reader.iter_decoded_messages(
            topics=["/abyss/simulation/joints", "/tf", "/tf_static"]
        ):
            if channel.topic == "/abyss/simulation/joints":
                names.add(tuple(message.name))
            else:
                frames |= {t.child_frame_id for t in message.transforms}
    assert names == {(*package.arm_joints, *package.gripper_joints)}
    assert {"boom", "stick", "wrist", "hand"} <= frames and not {"arm_link1", "arm_base"} & frames, frames
    assert {"base_link", "fls", "eye_l_optical_frame"} <= frames, frames  # the sonar's frame too
    assert {"beacon", "doppler", "ahrs", "baro"} <= frames, frames  # and the navigation sensors' sites
