"""The replay's comparison rule: two runs' messages agree where both sent them, and one run may
only have run on further (a run that stops once its mission is done ends where the stop reaches
it), never have sent other messages in between; the line that says how the run came out."""

from __future__ import annotations

from pathlib import Path

from abyss.validation.campaign.replay import _tail_only, outcome_line
from abyss.validation.scenario.runner import Result
from abyss.validation.scenario.spec import load_scenario

ROOT = Path(__file__).resolve().parents[2]


def sent(*items: tuple[str, str, int]) -> dict[tuple[str, str, int], bytes]:
    return {item: b"x" for item in items}


def test_a_run_that_went_on_further_is_a_tail_not_a_difference() -> None:
    short = sent(("onboard.mcap", "onboard/nav", 0), ("onboard.mcap", "onboard/nav", 1))
    longer = sent(*short, ("onboard.mcap", "onboard/nav", 2), ("onboard-1.mcap", "onboard/nav", 0))
    assert _tail_only(short, longer) and _tail_only(longer, short)
    assert _tail_only(short, short)


def test_messages_missing_in_between_or_on_both_sides_are_differences() -> None:
    first = sent(("onboard.mcap", "onboard/nav", 0), ("onboard.mcap", "onboard/nav", 2))
    gap = sent(*first, ("onboard.mcap", "onboard/nav", 1))
    assert not _tail_only(first, gap)  # the second run sent #1, the first skipped it
    other = sent(("onboard.mcap", "onboard/nav", 0), ("onboard.mcap", "onboard/joints", 0))
    assert not _tail_only(first, other)  # each sent something the other did not


def test_the_replay_says_the_runs_own_verdict(tmp_path: Path) -> None:
    """A run that reached its duration fails its scenario: FAIL, and the verdict `incomplete` that
    abyss up gave it, not the scenario's word `failed`."""
    scenario = load_scenario(ROOT / "scenarios" / "nominal.toml")
    ran_out = Result(scenario, tmp_path, [], False, 1.0, run_verdict="incomplete")
    line = outcome_line(ran_out)
    assert line.startswith("FAIL (verdict incomplete)") and "failed" not in line, line
    done = Result(scenario, tmp_path, [], True, 1.0, run_verdict="done")
    assert outcome_line(done) == "PASS (verdict done): every assertion held"
    crashed = Result(scenario, tmp_path, [], False, 1.0, error="the system did not come up:\n...")
    assert outcome_line(crashed) == "FAIL (verdict none): the system did not come up:"
