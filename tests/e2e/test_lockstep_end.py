"""A lockstep run that stops when its mission is done ends on the same period every time: the
end is decided on the simulated clock (shore's first status that says done, plus the lease), and
the simulation holds there until the stations are stopped, so two runs of one seed record the
same rows to the last."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import Up

from abyss.launch.control_record import CONTROL_FILE, PANEL_FILE
from abyss.launch.supervise import LEASE_S

pytestmark = pytest.mark.timeout(200)

# the shortest mission that still ends done: one waypoint a metre ahead of the start, no arm
# goal, no interventions (done at about 8 simulated seconds)
SHORT_MISSION = ("--set", "mission.waypoints=[[1.0, 0, -5.0, 0]]", "--set", "mission.interventions=[]")


def _stopped_when_done(out: Path) -> Up:
    up = Up(out, "--time", "lockstep", "--system", "e2e-lockstep-end", "--viewer", "none", "--record", "none",
            *SHORT_MISSION)  # fmt: skip
    assert up.wait(120) == 0, up.output()
    return up


def test_a_lockstep_run_stopped_when_done_ends_on_the_same_period_every_time(tmp_path: Path) -> None:
    first = _stopped_when_done(tmp_path / "a")
    second = _stopped_when_done(tmp_path / "b")
    a, b = tmp_path / "a", tmp_path / "b"
    summaries = first.summary(), second.summary()
    for summary in summaries:
        assert summary["verdict"] == "done" and not summary["keep_running"], summary["failure"]
    done_s = summaries[0]["mission_done_s"]
    assert done_s == summaries[1]["mission_done_s"] and 0 < done_s < 30  # shore's status's period
    rows = [(run / CONTROL_FILE).read_text().splitlines() for run in (a, b)]
    assert len(rows[0]) > 20 and rows[0] == rows[1], (len(rows[0]), len(rows[1]))
    assert (a / CONTROL_FILE).read_bytes() == (b / CONTROL_FILE).read_bytes()
    assert (a / PANEL_FILE).read_bytes() == (b / PANEL_FILE).read_bytes()
    # the records go on to the lease's end past the done, and stop there: onboard's last row is
    # the period before the one the simulation held at
    last_s = float(rows[0][-1].split(",")[0])
    assert done_s + LEASE_S - 0.15 < last_s < done_s + LEASE_S, (done_s, last_s)
    # and every station ran the same periods: each loop ticked as often in both runs
    loops = [{name: s.get("loops") for name, s in summary["stations"].items()} for summary in summaries]
    assert loops[0] == loops[1]
    assert f"mission complete at t={done_s:.1f} s simulated" in first.output()
