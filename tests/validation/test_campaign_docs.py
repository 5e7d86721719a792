"""docs/campaigns.md's campaign files, each loaded as a file in the repository's `campaigns/`
folder would be (its scenario paths relative to it), so that the page cannot name a field,
a matrix key or a scenario that does not exist; and its account of what a run asks Ray for."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import pytest

from abyss.validation.campaign.execute import task_cores
from abyss.validation.campaign.plan import plan
from abyss.validation.campaign.spec import load_campaign
from abyss.validation.scenario import capacity

ROOT = Path(__file__).resolve().parents[2]
PAGE = ROOT / "docs" / "campaigns.md"


def toml_examples() -> list[str]:
    return re.findall(r"```toml\n(.*?)```", PAGE.read_text(), re.DOTALL)


def test_the_page_has_its_examples() -> None:
    assert len(toml_examples()) >= 2


@pytest.mark.parametrize("index", range(len(toml_examples())))
def test_each_example_loads_as_a_campaign_file(tmp_path: Path, index: int) -> None:
    """In `<tmp>/campaigns/`, beside a copy of the scenario library in `<tmp>/scenarios/`, as the
    shipped campaigns sit in the repository."""
    shutil.copytree(ROOT / "scenarios", tmp_path / "scenarios")
    (tmp_path / "campaigns").mkdir()
    path = tmp_path / "campaigns" / "example.toml"
    path.write_text(toml_examples()[index])
    campaign = load_campaign(path)  # the file, every scenario it names and every matrix key
    assert campaign.scenarios and campaign.seeds
    assert plan(campaign)


def test_a_run_asks_for_the_measured_cost_over_the_headroom_in_lockstep_as_in_real_time(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The page: a system measured at 0.464 cores asks for 0.58 in lockstep (not a whole core),
    0.75 before anything was measured, a whole core over the headroom at speed max."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    campaign = load_campaign(ROOT / "campaigns" / "library.toml")
    lockstep = [r for r in plan(campaign) if r.scenario.time.mode == "lockstep"]
    assert lockstep
    assert task_cores(lockstep) == 0.75
    capacity.cost_file().parent.mkdir(parents=True)
    capacity.cost_file().write_text('{"cores": [0.464]}')
    assert task_cores(lockstep) == 0.58
    text = " ".join(PAGE.read_text().split())
    assert "measured at 0.464 cores asks for 0.58 in lockstep" in text
    assert "before anything was measured each asks for 0.75" in text
