"""The campaign store: records survive a driver killed mid-line and are counted once; the plan
file round-trips and guards --resume; a run's figures and record come from what it left."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest
from campaign_files import CAMPAIGN, record, write_files

from abyss.common.errors import ConfigError
from abyss.launch.control_record import COLUMNS, CONTROL_FILE
from abyss.validation.campaign.plan import plan, shard
from abyss.validation.campaign.spec import load_campaign
from abyss.validation.campaign.store import RESULTS_FILE, RunRecord, Store, figures, record_of
from abyss.validation.campaign.version import abyss_version
from abyss.validation.scenario.checks import Verdict
from abyss.validation.scenario.runner import Result


def test_a_record_round_trips_through_json(tmp_path: Path) -> None:
    run = plan(load_campaign(write_files(tmp_path)))[0]
    made = record(run, False, wrong=("stations",))
    assert RunRecord.from_json(json.loads(json.dumps(made.to_json()))) == made


def test_the_store_survives_a_torn_last_line_and_goes_on(tmp_path: Path) -> None:
    runs = plan(load_campaign(write_files(tmp_path)))
    store = Store(tmp_path / "c")
    for run in runs[:3]:
        store.add(record(run, True))
    whole = json.dumps(record(runs[3], True).to_json())
    with (store.dir / RESULTS_FILE).open("a") as f:
        f.write(whole[: len(whole) // 2])  # the driver killed mid-write
    assert list(store.records()) == [r.run_id for r in runs[:3]]
    store.add(record(runs[4], False))  # --resume appends after the torn line, not onto it
    assert list(store.records()) == [r.run_id for r in (*runs[:3], runs[4])]
    assert store.records()[runs[4].run_id].passed is False
    assert store.duplicates() == 0


def test_a_second_record_of_a_run_is_ignored_and_counted(tmp_path: Path) -> None:
    runs = plan(load_campaign(write_files(tmp_path)))
    store = Store(tmp_path / "c")
    store.add(record(runs[0], True))
    store.add(record(runs[1], True))
    store.add(record(runs[0], False))  # retried on another node after its first result came back
    assert store.duplicates() == 1
    assert len(store.records()) == 2 and store.records()[runs[0].run_id].passed is True
    assert Store(tmp_path / "empty").records() == {} and Store(tmp_path / "empty").duplicates() == 0


def test_the_plan_file_round_trips_and_guards_resume(tmp_path: Path) -> None:
    campaign = load_campaign(
        write_files(tmp_path, CAMPAIGN + 'keep = "all"\n[min_pass_rate_of]\nbeta = 0.5\n')
    )
    runs = plan(campaign)
    store = Store(tmp_path / "c")
    store.write_plan(campaign, runs, "1+abc", (2, 3))
    planned = store.read_plan()
    assert (planned.campaign, planned.version, planned.shard, planned.keep) == (
        "small",
        "1+abc",
        "2/3",
        "all",
    )
    assert list(planned.all_runs) == runs
    assert planned.runs == shard(runs, 2, 3)
    assert planned.min_rate("beta") == 0.5 and planned.min_rate("alpha") == 1.0
    assert store.check_plan(runs, "1+abc", (2, 3)) == planned
    for args, says in [
        ((runs, "1+abd", (2, 3)), "abyss changed: planned with 1+abc, this is 1+abd"),
        ((runs[:-1], "1+abc", (2, 3)), "the campaign changed"),
        ((runs, "1+abc", None), "planned as shard 2/3, asked all"),
    ]:
        with pytest.raises(ConfigError) as error:
            store.check_plan(*args)
        assert says in str(error.value) and error.value.field == "--resume"
    with pytest.raises(ConfigError, match="no campaign plan here"):
        Store(tmp_path / "elsewhere").read_plan()


def test_sessions_wall_times_add_up(tmp_path: Path) -> None:
    store = Store(tmp_path / "c")
    assert store.wall_s() == 0.0
    store.dir.mkdir()
    store.add_wall(100.0)
    store.add_wall(20.5)
    assert store.wall_s() == 120.5


SUMMARY = {  # the fields of a summary.json the figures come from (launch/summarise.py)
    "wall_s": 50.0,
    "mission_done_s": 41.5,
    "stations": {
        "simulation": {"cpu": {"cpu_s": 20.0, "wall_s": 49.0, "cores": 0.4}},
        "onboard": {"cpu": {"cpu_s": 10.0, "wall_s": 49.0, "cores": 0.2}},
        "vessel": {"external": True, "alive_seen": True},
    },
    "control": {"position_error_m": 0.002, "ee_position_error_m": 0.004, "ee_orientation_error_deg": 0.3},
    "interventions": [
        {"part": "valve_1", "target_deg": 90.0, "tolerance_deg": 5.0, "truth_deg": 87.5, "success": True},
        {"part": "lever_0", "target_deg": -45.0, "tolerance_deg": 3.0, "truth_deg": None, "success": False},
    ],
    "scene": {"occupied_cells": 9462},
    "time": {"mode": "lockstep", "speed": "1", "sim_s": 45.25},
    "simulation": {"sim_time_s": 46.0},
}


def _control_csv(path: Path, failsafe_at_s: float | None) -> Path:
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, COLUMNS, restval="0")
        writer.writeheader()
        for i in range(40):
            t = 0.5 * i
            failsafe = "tether lost" if failsafe_at_s is not None and t >= failsafe_at_s else ""
            writer.writerow({"sim_time_s": t, "mode": "waypoint", "failsafe": failsafe})
    return path


def test_a_runs_figures_come_from_its_summary_and_control_record(tmp_path: Path) -> None:
    found = figures(SUMMARY, _control_csv(tmp_path / CONTROL_FILE, 12.5))
    assert found == {
        "mission_s": 41.5,
        "vehicle_error_m": 0.002,
        "ee_error_m": 0.004,
        "ee_error_deg": 0.3,
        "failsafe_entry_s": 12.5,
        "scene_cells": 9462.0,
        "cores": pytest.approx(30.0 / 50.0),
        "sim_s": 45.25,
        "intervention_valve_1_error_deg": 2.5,
        "intervention_lever_0_error_deg": None,
    }
    assert figures(SUMMARY, _control_csv(tmp_path / "none.csv", None))["failsafe_entry_s"] is None
    empty = figures({})
    assert set(empty) == {"mission_s", "vehicle_error_m", "ee_error_m", "ee_error_deg", "failsafe_entry_s",
                          "scene_cells", "cores", "sim_s"}  # fmt: skip
    assert all(v is None for v in empty.values())


def test_a_finished_run_becomes_its_record(tmp_path: Path) -> None:
    run = plan(load_campaign(write_files(tmp_path)))[1]  # alpha, seed 1
    out_dir = tmp_path / "run"
    out_dir.mkdir()
    (out_dir / "summary.json").write_text(json.dumps(SUMMARY))
    _control_csv(out_dir / CONTROL_FILE, None)
    mission, stations = run.scenario.assertions
    verdicts = [Verdict(mission, False, "not done"), Verdict(stations, True, "all up")]
    result = Result(run.scenario, out_dir, verdicts, False, 61.0, run_verdict="incomplete")
    made = record_of(run, result, "10.0.0.2", "runs/x")
    assert (made.run_id, made.scenario, made.variant, made.values, made.seed) == (
        run.run_id, "alpha", "default", {}, 1,
    )  # fmt: skip
    assert (made.version, made.time, made.replayable, made.node, made.kept) == (
        abyss_version(), "lockstep", True, "10.0.0.2", "runs/x",
    )  # fmt: skip
    assert (made.passed, made.outcome, made.error) == (False, "failed", "")
    assert made.wrong == ["mission_done within_s=25.0"]
    assert made.verdicts[0] == {
        "assertion": "mission_done within_s=25.0",
        "kind": "mission_done",
        "passed": False,
        "detail": "not done",
    }
    assert (made.wall_s, made.sim_s, made.core_s) == (61.0, 45.25, 30.0)
    assert made.figures["mission_s"] == 41.5
