"""The replay's comparison rule: two runs' messages agree where both sent them, and one run may
only have run on further (a run that stops once its mission is done ends where the stop reaches
it), never have sent other messages in between."""

from __future__ import annotations

from abyss.validation.campaign.replay import _tail_only


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
