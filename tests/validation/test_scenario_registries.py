"""Event and assertion kinds are registries: a kind added from here (one small class, one
function, a line each) is read from a scenario file, described, dispatched (apply, and in
lockstep settled) and judged like the built-in ones; a campaign's matrix takes its fields."""

from __future__ import annotations

import dataclasses
import tomllib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, cast

import pytest

from abyss.common.errors import ConfigError
from abyss.common.reading import OneOf
from abyss.validation.campaign.spec import event_fields, scenario_with
from abyss.validation.scenario.checks import CHECKS, Run, judge
from abyss.validation.scenario.events import EVENTS, Context, Event, action_of
from abyss.validation.scenario.held import carry_out
from abyss.validation.scenario.runner import run_scenario
from abyss.validation.scenario.spec import load_scenario, scenario_of

CALLS: list[tuple[str, str]] = []  # what the test kinds were asked to do, in order


@dataclass(frozen=True, kw_only=True)
class Beep(Event):
    """A test event: a note, some times."""

    note: Annotated[str, OneOf(("low", "high"))]
    times: int = 1

    def describe(self) -> str:
        return f"beep {self.note} x{self.times}"

    def apply(self, ctx: Context) -> str:
        CALLS.append(("apply", self.note))
        return self.describe()

    def settled(self, ctx: Context) -> str:
        CALLS.append(("settled", self.note))
        return ", heard"


def beeped(run: Run, min_beeps: int = 1, note: str = "") -> tuple[bool, str]:
    """A test check: the test events applied, at least `min_beeps` (of `note`, if named)."""
    beeps = [n for what, n in CALLS if what == "apply" and note in ("", n)]
    return len(beeps) >= min_beeps, f"{len(beeps)} beeps (verdict {run.summary.get('verdict', '-')})"


SCENARIO = """
name = "beeping"
use = "degradation"
duration_s = 6
stop_when_done = false

[config]
"time.mode" = "lockstep"

[[events]]
at_s = 2
action = "beep"
note = "high"
times = 3

[[assert]]
kind = "beeped"
min_beeps = 1
note = "high"

[[assert]]
kind = "stations"
"""


@pytest.fixture(autouse=True)
def registered(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    monkeypatch.setitem(EVENTS, "beep", Beep)
    monkeypatch.setitem(CHECKS, "beeped", beeped)
    CALLS.clear()
    yield
    CALLS.clear()


def test_a_new_kind_is_read_from_a_file_and_described(tmp_path: Path) -> None:
    path = tmp_path / "beeping.toml"
    path.write_text(SCENARIO)
    scenario = load_scenario(path)
    (event,) = scenario.events
    assert event == Beep(at_s=2.0, note="high", times=3) and action_of(event) == "beep"
    assert event.describe() == "beep high x3" and event.when() == "t=2 s"
    assert scenario.holds_s == (2.0,)  # lockstep: the simulation holds where it lands
    assert [a.describe() for a in scenario.assertions] == ["beeped min_beeps=1 note=high", "stations"]


@pytest.mark.parametrize(("event", "field", "said"), [
    ({"note": "mid"}, "events[0].note", "'mid' not one of low, high"),
    ({}, "events[0].note", "is required: one of low, high"),
    ({"note": "low", "times": "many"}, "events[0].times", "expected a whole number"),
    ({"note": "low", "volume": 3}, "events[0].volume", "allowed: at_s, note, phase, times (a beep event)"),
])  # fmt: skip
def test_a_new_event_kind_is_checked_as_its_fields_are_typed(event: dict, field: str, said: str) -> None:
    table = {"name": "x", "use": "degradation", "duration_s": 5, "assert": [{"kind": "stations"}]}
    with pytest.raises(ConfigError) as error:
        scenario_of({**table, "events": [{"at_s": 1, "action": "beep", **event}]}, "bad.toml")
    assert error.value.field == field and said in error.value.reason, str(error.value)


def test_a_new_assertion_kind_takes_its_fields_from_its_check() -> None:
    table = {"name": "x", "use": "degradation", "duration_s": 5}
    with pytest.raises(ConfigError, match=r"assert\[0\]\.min_beep: unknown field; allowed: min_beeps, note"):
        scenario_of({**table, "assert": [{"kind": "beeped", "min_beep": 1}]}, "bad.toml")
    with pytest.raises(ConfigError, match=r"assert\[0\]\.min_beeps: expected a whole number"):
        scenario_of({**table, "assert": [{"kind": "beeped", "min_beeps": 0.5}]}, "bad.toml")
    with pytest.raises(ConfigError, match=r"assert\[0\]\.kind: 'bleeped' not one of .*, beeped"):
        scenario_of({**table, "assert": [{"kind": "bleeped"}]}, "bad.toml")


def test_a_new_event_is_dispatched_and_its_assertion_judged() -> None:
    scenario = scenario_of(tomllib.loads(SCENARIO))
    (event,) = scenario.events
    ctx = Context(cast(Any, None), "beeping", cast(Any, None), restart=False, timeout_s=1.0)
    assert carry_out(event, ctx) == "beep high x3"  # real time: applied, nothing to wait for
    assert CALLS == [("apply", "high")]
    ctx.holds = cast(Any, object())  # lockstep: applied, then waited on before the release
    assert carry_out(event, ctx) == "beep high x3, heard"
    assert CALLS == [("apply", "high"), ("apply", "high"), ("settled", "high")]
    held, _ = judge(Run({"verdict": "incomplete"}), scenario.assertions)
    assert held.passed and held.detail == "2 beeps (verdict incomplete)"
    CALLS.clear()
    assert not judge(Run({}), scenario.assertions)[0].passed


def test_a_campaign_matrix_takes_a_new_event_kinds_fields(tmp_path: Path) -> None:
    assert {"note", "times"} <= set(event_fields())
    path = tmp_path / "beeping.toml"
    low = scenario_with(SCENARIO, path, [("events[0].note", "low"), ("time.mode", "sim")], seed=4)
    assert low.events[0] == dataclasses.replace(Beep(at_s=2.0, note="high", times=3), note="low")
    assert low.configuration.time.mode == "sim" and low.configuration.seed == 4


@pytest.mark.e2e
@pytest.mark.timeout(300)
def test_a_new_kind_in_a_real_lockstep_run(tmp_path: Path) -> None:
    """A whole system in lockstep: the simulation holds at 2 s, the test event is applied and
    settled there, then released; the test assertion is judged on the run."""
    path = tmp_path / "beeping.toml"
    path.write_text(SCENARIO)
    lines: list[str] = []
    result = run_scenario(load_scenario(path), tmp_path / "run", 0, lines.append)
    assert result.passed, [str(v) for v in result.verdicts] + [result.error] + lines
    assert CALLS == [("apply", "high"), ("settled", "high")]
    assert any("beep high x3, heard" in line for line in lines), lines
    assert (tmp_path / "run" / "scenario-config.json").exists()
