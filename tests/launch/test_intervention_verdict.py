"""An intervention is judged on the simulation's truth of the panel, not on what onboard says;
and an intent that does not parse is refused at the command line, before anything is sent."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np

from abyss.bus import description
from abyss.bus.session import open_session, zenoh_config
from abyss.common.ports import free_port
from abyss.config.system import MissionConfig
from abyss.description.robot import robot_at
from abyss.description.site import site_at
from abyss.interface.messages import PanelState
from abyss.interface.system_description import description_payload
from abyss.launch.verdict import interventions_summary, render_summary

panel = site_at("").panel  # the shipped site's

PARTS = (*panel.valves, *panel.levers)


def state(**angles_deg: float) -> PanelState:
    return PanelState(PARTS, np.radians([angles_deg.get(p, 0.0) for p in PARTS]), np.zeros(len(PARTS)), 1.0)


def test_each_intervention_is_judged_on_the_true_angle_against_its_target() -> None:
    mission = MissionConfig(
        arm_target=(), interventions=(("valve_1", "90"), ("lever_0", "down"), ("valve_1", "-45"))
    )
    judged = interventions_summary(mission, panel, state(), state(valve_1=43.0, lever_0=-44.0))
    assert [(j["part"], j["target_deg"], j["success"]) for j in judged] == [
        ("valve_1", 90.0, False),
        ("lever_0", -45.0, True),
        ("valve_1", 45.0, True),
    ]  # 90 then -45
    judged = interventions_summary(mission, panel, state(), state(valve_1=84.0, lever_0=-40.0))
    assert [j["success"] for j in judged] == [False, False, False]  # 6 deg short; 5 from the stop
    unseen = interventions_summary(mission, panel, None, None)  # no truth came
    assert all(not j["success"] and j["truth_deg"] is None for j in unseen)
    summary = {
        "system": "s",
        "verdict": "incomplete",
        "failure": "",
        "startup_s": 1.0,
        "wall_s": 9.0,
        "stations": {},
        "links": {},
        "mission": None,
        "control": None,
        "scene": None,
        "simulation": None,
        "interventions": judged,
    }
    assert "valve_1 at 84.0 deg, target 90 +- 5 deg: NOT DONE" in render_summary(summary)
    summary["mission"] = {
        "mode": "reached",
        "waypoint_index": 3,
        "waypoints_total": 3,
        "done": False,
        "intervention_target": "valve_1",
        "intervention_phase": "failed",
        "intervention_reason": "valve_1 does not turn",
    }
    assert "done: False; valve_1 failed: valve_1 does not turn" in render_summary(summary)


def test_a_wrong_intent_fails_at_the_command_line_with_what_is_allowed() -> None:
    """Against the running system's panel (a station's shell serves its description; here the
    shipped pair's, served as a shell does), before anything is sent."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = open_session(zenoh_config([endpoint], mode="router"), "the test's shore")
    served = description.serve(
        router, "default", "onshore", description_payload("default", robot_at(""), site_at(""))
    )
    try:
        for args, expected in (
            (["valve", "lever_0", "--turn", "90"], "lever_0 is a lever, not a valve"),
            (["valve", "valve_1"], "turned by an angle in [-180, 180] deg"),
            (["valve", "valve_7", "--turn", "90"], "valve_0, valve_1, valve_2, lever_0, lever_1"),
            (["lever", "lever_1", "--to", "sideways"], "invalid choice: 'sideways'"),
        ):
            done = subprocess.run(
                [sys.executable, "-m", "abyss.cli", "op", *args, "--timeout", "1", "--connect", endpoint],
                capture_output=True,
                text=True,
                timeout=60,
            )
            assert done.returncode == 2 and expected in done.stderr, (args, done.stdout, done.stderr)
    finally:
        served.undeclare()
        router.close()
    assert math.isclose(panel.intent("valve_2", "-30")[0], math.radians(-30))


def test_a_hybrid_run_says_its_interventions_and_a_restarts_drift_have_no_truth_to_judge_them() -> None:
    """Shore's word stands in for the truth, said as such; a restart's drift is not claimed 0 mm."""
    from abyss.config import load
    from abyss.interface.messages import MissionStatus
    from abyss.launch.summarise import hybrid_summary
    from abyss.launch.verdict import _restart_lines, hybrid_interventions

    config = load(overrides=['hybrid.vehicle=["nav", "joints"]'])
    status = MissionStatus("reached", 3, 3, 0.0, 0.0, "reached", 0.0, 0.0, "", 0, True, 1, 2)
    judged = hybrid_interventions(config.mission, status)
    assert [(i["part"], i["success"], i["done_on_shore"]) for i in judged] == [
        ("valve_1", None, True),
        ("lever_0", None, False),
    ]
    restart = {"station": "simulation", "exit_code": -9, "t_s": 8.9, "down_s": 2.8, "drift_m": 0.0}
    hybrid = {"restarts": [restart], "hybrid": hybrid_summary(config)}
    assert "no truth to tell how far the vehicle strayed" in _restart_lines(hybrid)[0]
    assert "strayed 0 mm" in _restart_lines({"restarts": [restart]})[0]
