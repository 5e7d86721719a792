"""Campaign and scenario files the campaign tests share: two small scenarios (one with a link
event, one with an external station and a fault) in `<tmp>/scenarios/`, a campaign file in
`<tmp>/campaigns/` naming them by a glob relative to itself, and records made by hand."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from abyss.validation.campaign.plan import RunSpec
from abyss.validation.campaign.store import RunRecord

ROOT = Path(__file__).resolve().parents[2]
SCENARIO_A = """\
name = "alpha"
use = "degradation"
duration_s = 30

[[events]]
at_s = 5
action = "link"
hop = "satellite"
profile = "satellite-storm"

[[assert]]
kind = "mission_done"
within_s = 25

[[assert]]
kind = "stations"
"""
SCENARIO_B = """\
name = "beta"
use = "distributed"
duration_s = 20
external = ["onboard"]

[[events]]
at_s = 3
action = "fault"
fault = "noise"
target = "usbl"
value = 3.0

[[assert]]
kind = "stations"
"""
CAMPAIGN = """\
name = "small"
scenarios = ["../scenarios/*.toml"]
seeds = 3
"""


def write_files(tmp: Path, campaign: str = CAMPAIGN) -> Path:
    """The two scenarios and the campaign file `campaign`; the campaign file's path."""
    (tmp / "scenarios").mkdir(exist_ok=True)
    (tmp / "scenarios" / "alpha.toml").write_text(SCENARIO_A)
    (tmp / "scenarios" / "beta.toml").write_text(SCENARIO_B)
    (tmp / "campaigns").mkdir(exist_ok=True)
    path = tmp / "campaigns" / "small.toml"
    path.write_text(campaign)
    return path


def record(
    run: RunSpec, passed: bool, wrong: tuple[str, ...] = (), error: str = "", **more: Any
) -> RunRecord:
    """A run's record as a finished run would leave it, figures from its seed."""
    verdicts = [
        {"assertion": a.describe(), "kind": a.kind, "passed": a.describe() not in wrong, "detail": "-"}
        for a in run.scenario.assertions
    ]
    fields: dict[str, Any] = {
        "run_id": run.run_id,
        "scenario": run.scenario_name,
        "variant": run.variant.name,
        "values": run.variant.as_dict(),
        "seed": run.seed,
        "version": "test",
        "time": run.time,
        "replayable": run.replayable,
        "passed": passed,
        "outcome": "done" if passed else "failed",
        "error": error,
        "verdicts": [] if error else verdicts,
        "wrong": list(wrong),
        "figures": {"mission_s": 20.0 + run.seed, "cores": 1.5, "intervention_valve_1_error_deg": None},
        "wall_s": 30.0,
        "sim_s": 25.0,
        "core_s": 45.0,
        "node": f"node-{run.seed % 2}",
        "kept": "" if passed else f"runs/{run.run_id}",
    }
    return RunRecord(**{**fields, **more})
