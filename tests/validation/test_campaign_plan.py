"""A campaign's plan: scenarios x variants x seeds in a stable order; run ids that change with
what makes a run and only with it; shards that partition the plan; each variant landing in the
scenario a run gets; RunSpec's JSON round trip."""

from __future__ import annotations

import json
import pickle
from pathlib import Path

import pytest
from campaign_files import CAMPAIGN, write_files

from abyss.common.errors import ConfigError
from abyss.validation.campaign.plan import RunSpec, Variant, parse_shard, plan, run_id, shard, spec_of
from abyss.validation.campaign.spec import load_campaign

MATRIX = """
[matrix]
"links.satellite" = ["satellite", "satellite-storm"]
"events[0].at_s" = [5.0, 10]
"""


def test_the_plan_is_scenarios_times_variants_times_seeds_in_a_stable_order(tmp_path: Path) -> None:
    campaign = load_campaign(write_files(tmp_path, CAMPAIGN + MATRIX))
    runs = plan(campaign)
    assert len(runs) == 2 * 4 * 3
    assert [(r.scenario_name, r.variant.name, r.seed) for r in runs[:7]] == [
        ("alpha", "links.satellite=satellite events[0].at_s=5", 0),
        ("alpha", "links.satellite=satellite events[0].at_s=5", 1),
        ("alpha", "links.satellite=satellite events[0].at_s=5", 2),
        ("alpha", "links.satellite=satellite events[0].at_s=10", 0),
        ("alpha", "links.satellite=satellite events[0].at_s=10", 1),
        ("alpha", "links.satellite=satellite events[0].at_s=10", 2),
        ("alpha", "links.satellite=satellite-storm events[0].at_s=5", 0),
    ]
    assert [r.scenario_name for r in runs[12:]] == ["beta"] * 12
    assert len({r.run_id for r in runs}) == len(runs)
    assert [r.run_id for r in plan(load_campaign(campaign.path))] == [r.run_id for r in runs]


def test_no_matrix_is_the_default_variant(tmp_path: Path) -> None:
    runs = plan(load_campaign(write_files(tmp_path)))
    assert {r.variant.name for r in runs} == {"default"} and len(runs) == 2 * 3
    assert (
        Variant((("simulation.current_sigma_mps", 0.30000000000000004),)).name
        == "simulation.current_sigma_mps=0.3"
    )


def test_run_ids_change_with_what_makes_a_run_and_only_with_it() -> None:
    variant = Variant((("links.satellite", "satellite"),))
    same = run_id("text", variant, 3, "lockstep", "1+abc")
    assert run_id("text", Variant((("links.satellite", "satellite"),)), 3, "lockstep", "1+abc") == same
    assert len(same) == 16 and int(same, 16) >= 0
    others = {
        run_id("text\n# a comment", variant, 3, "lockstep", "1+abc"),
        run_id("text", Variant((("links.satellite", "satellite-storm"),)), 3, "lockstep", "1+abc"),
        run_id("text", Variant(()), 3, "lockstep", "1+abc"),
        run_id("text", variant, 4, "lockstep", "1+abc"),
        run_id("text", variant, 3, "sim", "1+abc"),
        run_id("text", variant, 3, "lockstep", "1+abd"),
    }
    assert same not in others and len(others) == 6


def test_a_scenario_file_changed_gives_its_runs_new_ids(tmp_path: Path) -> None:
    path = write_files(tmp_path)
    before = plan(load_campaign(path))
    alpha = tmp_path / "scenarios" / "alpha.toml"
    alpha.write_text(alpha.read_text() + "# reworded\n")
    after = plan(load_campaign(path))
    changed = {b.scenario_name for b, a in zip(before, after, strict=True) if b.run_id != a.run_id}
    assert changed == {"alpha"}


@pytest.mark.parametrize("n", [1, 2, 3, 5, 7])
def test_shards_partition_the_plan(tmp_path: Path, n: int) -> None:
    runs = plan(load_campaign(write_files(tmp_path, CAMPAIGN + MATRIX)))
    slices = [shard(runs, k, n) for k in range(1, n + 1)]
    ids = [r.run_id for s in slices for r in s]
    assert sorted(ids) == sorted(r.run_id for r in runs) and len(ids) == len(set(ids))
    assert max(map(len, slices)) - min(map(len, slices)) <= 1


@pytest.mark.parametrize("text", ["0/3", "4/3", "a/b", "3", "", "1/0", "-1/2", "1/2/3"])
def test_a_bad_shard_is_refused(text: str) -> None:
    with pytest.raises(ConfigError) as error:
        parse_shard(text)
    assert error.value.field == "--shard" and "K/N with 1 <= K <= N" in error.value.reason
    assert parse_shard("2/3") == (2, 3) and parse_shard("1/1") == (1, 1)


def test_each_variant_lands_in_the_scenario_its_run_gets(tmp_path: Path) -> None:
    matrix = """
[matrix]
"links.tether" = ["tether-degraded"]
"simulation.current_sigma_mps" = [0.25]
"simulation.current_profile" = [[[-8.0, 0.1, 0.0, 0.0]]]
"simulation.water" = ["IB"]
"events[0].at_s" = [7.5]
"""
    runs = plan(load_campaign(write_files(tmp_path, CAMPAIGN + matrix)))
    for run in runs:
        scenario = run.scenario
        assert scenario.links["tether"] == "tether-degraded"
        assert scenario.events[0].at_s == 7.5
        config = scenario.configuration  # as `abyss up --config` reads it
        assert config.simulation.current_sigma_mps == 0.25
        assert config.simulation.current_profile == ((-8.0, 0.1, 0.0, 0.0),)
        assert config.simulation.water == "IB"
        assert config.seed == run.seed


def test_the_time_source_a_run_really_has(tmp_path: Path) -> None:
    runs = plan(load_campaign(write_files(tmp_path)))
    alpha, beta = runs[0], runs[3]
    assert (alpha.time, alpha.replayable, alpha.why_not_replayable) == ("lockstep", True, "")
    assert alpha.scenario.configuration.time.mode == "lockstep"
    assert (beta.time, beta.replayable) == ("real", False)  # an external station keeps the wall clock
    assert "external onboard" in beta.why_not_replayable
    sim = plan(load_campaign(write_files(tmp_path, CAMPAIGN + 'time = "sim"\n')))
    assert (sim[0].time, sim[0].replayable) == ("sim", False)
    assert "only statistically" in sim[0].why_not_replayable


def test_a_run_spec_goes_through_json_and_pickle_unchanged_without_its_file(tmp_path: Path) -> None:
    runs = plan(load_campaign(write_files(tmp_path, CAMPAIGN + MATRIX)))
    (tmp_path / "scenarios" / "alpha.toml").unlink()  # replay rebuilds it from the text
    (tmp_path / "scenarios" / "beta.toml").unlink()
    for run in runs:
        again = RunSpec.from_json(json.loads(json.dumps(run.to_json())))
        assert again == run
        assert again.scenario == run.scenario
        assert pickle.loads(pickle.dumps(run)) == run


def test_a_run_spec_rebuilt_keeps_its_written_id() -> None:
    variant = Variant(())
    text = """name = "x"\nuse = "degradation"\nduration_s = 10\n[[assert]]\nkind = "stations"\n"""
    run = spec_of(text, Path("x.toml"), variant, 1, "lockstep", "old-version")
    assert RunSpec.from_json(run.to_json()).run_id == run.run_id
