"""A campaign's report from records made by hand: counts, pass rates, Wilson intervals, flaky
marks, assertion failure counts, pending runs, JUnit failures, replay lines, plots; two shards
merged give the one campaign's report; Wilson against values computed apart."""

from __future__ import annotations

import json
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from campaign_files import CAMPAIGN, record, write_files

from abyss.common.errors import ConfigError
from abyss.validation.campaign.case import RUN_ERROR
from abyss.validation.campaign.figures import pass_rates
from abyss.validation.campaign.plan import RunSpec, plan, shard
from abyss.validation.campaign.report import build_report, merge
from abyss.validation.campaign.spec import Campaign, load_campaign
from abyss.validation.campaign.stats import wilson
from abyss.validation.campaign.store import RunRecord, Store

MATRIX = """
[min_pass_rate_of]
beta = 0.5

[matrix]
"links.satellite" = ["satellite", "satellite-storm"]
"simulation.current_sigma_mps" = [0.0]
"""
STORM = "links.satellite=satellite-storm simulation.current_sigma_mps=0"
CLEAR = "links.satellite=satellite simulation.current_sigma_mps=0"
MISSION = "mission_done within_s=25.0"


def wilson_apart(passes: int, runs: int, z: float = 1.96) -> tuple[float, float]:
    """The Wilson score interval as Wilson (1927) wrote it, for the test alone."""
    p = passes / runs
    centre = p + z**2 / (2 * runs)
    spread = z * math.sqrt(p * (1 - p) / runs + z**2 / (4 * runs**2))
    return (centre - spread) / (1 + z**2 / runs), (centre + spread) / (1 + z**2 / runs)


@pytest.mark.parametrize(("passes", "runs"), [(0, 10), (10, 10), (5, 10), (3, 5), (1, 1), (17, 20)])
def test_wilson_against_the_formula_and_published_values(passes: int, runs: int) -> None:
    low, high = wilson(passes, runs)
    assert (low, high) == pytest.approx(wilson_apart(passes, runs), abs=1e-12)
    assert 0.0 <= low <= passes / runs <= high <= 1.0


def test_wilson_at_the_ends_and_in_the_middle() -> None:
    assert wilson(0, 10) == (0.0, pytest.approx(0.2775, abs=1e-4))  # z^2 / (n + z^2)
    assert wilson(10, 10) == (pytest.approx(0.7225, abs=1e-4), 1.0)
    assert wilson(5, 10) == (pytest.approx(0.2366, abs=1e-4), pytest.approx(0.7634, abs=1e-4))
    assert wilson(0, 0) == (0.0, 1.0)


def _records(runs: list[RunSpec]) -> dict[str, RunRecord]:
    """alpha clear: 5/5; alpha storm: 3/5 (seed 3 misses the mission, seed 4 that and a station);
    beta clear: 0/5 (seed 0 never came up); beta storm: 4/4 and seed 4 pending."""
    made = {}
    for run in runs:
        case = (run.scenario_name, run.variant.name)
        if case == ("alpha", STORM) and run.seed >= 3:
            made[run.run_id] = record(run, False, (MISSION,) + (("stations",) if run.seed == 4 else ()))
        elif case == ("beta", CLEAR):
            made[run.run_id] = (
                record(run, False, error="the system did not come up:\n...")
                if run.seed == 0
                else record(run, False, ("stations",))
            )
        elif case == ("beta", STORM) and run.seed == 4:
            continue
        else:
            made[run.run_id] = record(run, True)
    return made


def _campaign(tmp_path: Path) -> tuple[Campaign, list[RunSpec]]:
    campaign = load_campaign(write_files(tmp_path, CAMPAIGN.replace("seeds = 3", "seeds = 5") + MATRIX))
    return campaign, plan(campaign)


def test_the_report_counts_rates_intervals_flaky_runs_and_failures(tmp_path: Path) -> None:
    campaign, runs = _campaign(tmp_path)
    out = tmp_path / "c"
    report = build_report(runs, _records(runs), out, campaign.min_rate, 300.0, "small")
    data = json.loads((out / "report.json").read_text())
    assert data == report.data()
    cases = {(c["scenario"], c["variant"]): c for c in data["cases"]}
    assert list(cases) == [("alpha", CLEAR), ("alpha", STORM), ("beta", CLEAR), ("beta", STORM)]
    expected = {  # runs, passes, pending, flaky, ok, min rate
        ("alpha", CLEAR): (5, 5, 0, False, True, 1.0),
        ("alpha", STORM): (5, 3, 0, True, False, 1.0),
        ("beta", CLEAR): (5, 0, 0, False, False, 0.5),
        ("beta", STORM): (4, 4, 1, False, True, 0.5),
    }
    for key, (n, passes, pending, is_flaky, ok, min_rate) in expected.items():
        c = cases[key]
        assert (c["runs"], c["passes"], c["pending"], c["flaky"], c["ok"], c["min_pass_rate"]) == (
            n, passes, pending, is_flaky, ok, min_rate,
        ), key  # fmt: skip
        assert c["pass_rate"] == passes / n
        assert c["wilson_95"] == pytest.approx(list(wilson_apart(passes, n)), abs=1e-12)
    assert cases[("alpha", STORM)]["assertion_failures"] == {MISSION: 2, "stations": 1}
    assert cases[("beta", CLEAR)]["assertion_failures"] == {"stations": 4, RUN_ERROR: 1}
    assert cases[("alpha", CLEAR)]["assertion_failures"] == {}
    assert [r["seed"] for r in cases[("alpha", STORM)]["failing_runs"]] == [3, 4]
    assert cases[("alpha", STORM)]["figures"]["mission_s"] == {
        "n": 5,
        "median": 22.0,
        "min": 20.0,
        "max": 24.0,
    }
    assert (data["planned"], data["runs"], data["pending"], data["passed"]) == (20, 19, 1, False)
    assert not report.passed()
    assert data["cost"] == {
        "core_hours": pytest.approx(19 * 45.0 / 3600),
        "wall_s": 300.0,
        "runs_wall_s": 19 * 30.0,
        "sim_s": 19 * 25.0,
        "sim_s_per_wall_s": pytest.approx(19 * 25.0 / 300.0),
        "nodes": {"node-0": 11, "node-1": 8},  # even seeds on node-0, seed 4 of one case pending
    }


def test_the_margins_pool_each_axis_value_over_the_other_axes_and_scenarios(tmp_path: Path) -> None:
    campaign, runs = _campaign(tmp_path)
    report = build_report(runs, _records(runs), tmp_path / "c", campaign.min_rate)
    margins = report.data()["margins"]
    assert [(m["value"], m["passes"], m["runs"]) for m in margins["links.satellite"]] == [
        ("satellite", 5 + 0, 10),  # alpha clear 5/5, beta clear 0/5
        ("satellite-storm", 3 + 4, 9),  # alpha storm 3/5, beta storm 4/4 (one pending)
    ]
    assert margins["links.satellite"][1]["wilson_95"] == pytest.approx(list(wilson_apart(7, 9)), abs=1e-12)
    assert [(m["value"], m["runs"]) for m in margins["simulation.current_sigma_mps"]] == [(0.0, 19)]
    text = (tmp_path / "c" / "report.md").read_text()
    assert "## By `links.satellite`" in text and "| satellite-storm | 9 | 7 | 78 % |" in text


def test_a_report_whose_cases_all_reach_their_rates_passes(tmp_path: Path) -> None:
    campaign, runs = _campaign(tmp_path)
    report = build_report(runs, {r.run_id: record(r, True) for r in runs}, tmp_path / "c", campaign.min_rate)
    assert report.passed()
    assert not build_report(runs, {}, tmp_path / "d", campaign.min_rate).passed()  # all pending


def test_junit_fails_each_case_under_its_rate(tmp_path: Path) -> None:
    campaign, runs = _campaign(tmp_path)
    build_report(runs, _records(runs), tmp_path / "c", campaign.min_rate, 300.0, "small")
    suite = ET.parse(tmp_path / "c" / "junit.xml").getroot()
    assert (suite.get("tests"), suite.get("failures"), suite.get("skipped")) == ("4", "2", "0")
    cases = suite.findall("testcase")
    assert [(c.get("classname"), c.get("name")) for c in cases] == [
        ("campaign.alpha", CLEAR),
        ("campaign.alpha", STORM),
        ("campaign.beta", CLEAR),
        ("campaign.beta", STORM),
    ]
    failed = {c.get("classname") + " " + c.get("name", ""): c.find("failure") for c in cases}
    assert [k for k, f in failed.items() if f is not None] == [
        f"campaign.alpha {STORM}",
        f"campaign.beta {CLEAR}",
    ]
    message = failed[f"campaign.alpha {STORM}"].get("message", "")  # type: ignore[union-attr]
    assert message == "3/5 passed (60 %, 95 % interval 23 % to 88 %), min pass rate 100 %"


def test_the_markdown_names_failing_runs_and_how_they_replay_and_the_plots_exist(tmp_path: Path) -> None:
    campaign, runs = _campaign(tmp_path)
    records = _records(runs)
    out = tmp_path / "c"
    build_report(runs, records, out, campaign.min_rate, 300.0, "small")
    text = (out / "report.md").read_text()
    assert text.startswith("# Campaign small: FAIL")
    failing = [r for r in records.values() if r.scenario == "alpha" and not r.passed]
    for r in failing:
        assert f"`abyss campaign replay {out} {r.run_id}`" in text
    assert "replays only statistically (runs in real time: external onboard keeps the wall clock)" in text
    assert "**flaky**" in text and "1 runs pending" in text
    for name in ("mission_s", "cores", "pass_rate"):
        png = out / "plots" / f"{name}.png"
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert f"](plots/{name}.png)" in text
    assert not (out / "plots" / "intervention_valve_1_error_deg.png").exists()  # no run has it


def test_the_heat_map_pools_every_scenario_over_the_first_two_axes(tmp_path: Path) -> None:
    campaign, runs = _campaign(tmp_path)
    report = build_report(runs, _records(runs), tmp_path / "c", campaign.min_rate)
    rows, columns, passes, counted = pass_rates(
        report.cases, ("links.satellite", "simulation.current_sigma_mps")
    )
    assert (rows, columns) == (["satellite", "satellite-storm"], [0.0])
    assert passes.tolist() == [[5], [3 + 4]] and counted.tolist() == [[10], [9]]


def _store(
    directory: Path, campaign: Campaign, runs: list[RunSpec], records: list[RunRecord], **kw: object
) -> Store:
    store = Store(directory)
    store.write_plan(campaign, runs, "1+test", kw.get("shard"))  # type: ignore[arg-type]
    for r in records:
        store.add(r)
    store.add_wall(float(kw.get("wall_s", 0.0)))  # type: ignore[arg-type]
    return store


def test_two_shards_merged_give_the_one_campaigns_report(tmp_path: Path) -> None:
    campaign, runs = _campaign(tmp_path)
    records = _records(runs)
    whole = _store(tmp_path / "whole", campaign, runs, list(records.values()), wall_s=120.0)
    planned = whole.read_plan()
    one = build_report(planned.runs, whole.records(), whole.dir, planned.min_rate, whole.wall_s(), "small")
    parts = []
    for k in (1, 2):
        mine = [records[r.run_id] for r in shard(runs, k, 2) if r.run_id in records]
        parts.append(
            _store(tmp_path / f"shard{k}", campaign, runs, mine[::-1], shard=(k, 2), wall_s=60.0 + k)
        )
    parts[0].add(records[shard(runs, 1, 2)[0].run_id])  # a run recorded twice: counted once
    merged = merge([p.dir for p in parts], tmp_path / "merged")
    a, b = one.data(), merged.data()
    assert a.pop("cost")["wall_s"] == 120.0 and b.pop("cost")["wall_s"] == 61.0 + 62.0
    assert a == b
    assert json.loads((tmp_path / "merged" / "report.json").read_text())["cases"] == a["cases"]
    again = Store(tmp_path / "merged")
    assert again.read_plan().runs == runs and len(again.records()) == len(records) and again.wall_s() == 123.0
    kept = next(r.kept for r in again.records().values() if r.kept)
    assert kept.startswith("../shard") and (tmp_path / "merged" / kept).parent.parent.name.startswith("shard")


def test_merge_refuses_another_campaign_or_abyss_naming_both(tmp_path: Path) -> None:
    campaign, runs = _campaign(tmp_path)
    first = _store(tmp_path / "a", campaign, runs, [])
    other = Store(tmp_path / "b")
    other.write_plan(campaign, runs, "1+other")
    with pytest.raises(ConfigError) as error:
        merge([first.dir, other.dir], tmp_path / "m")
    assert "abyss 1+other" in str(error.value) and "abyss 1+test" in str(error.value)
    with pytest.raises(ConfigError, match="holds a campaign already"):
        merge([first.dir], first.dir)
