"""docs/scenarios.md cannot rot: every TOML example in it loads as written, and its tables of
event and assertion kinds are the registries', each kind with every field it takes."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from abyss.validation.scenario.checks import CHECKS, fields_of
from abyss.validation.scenario.events import EVENTS
from abyss.validation.scenario.events import fields_of as event_fields
from abyss.validation.scenario.spec import USES, ScenarioFile, load_scenario

DOC = Path(__file__).resolve().parents[2] / "docs" / "scenarios.md"
EXAMPLES = re.findall(r"```toml\n(.*?)```", DOC.read_text(), re.DOTALL)
COMMON = ("at_s", "phase")  # every event's, said once above the table


def table_of(section: str) -> dict[str, set[str]]:
    """The section's table: each row's first column's name -> the names its second one gives."""
    text = DOC.read_text().split(f"## {section}\n", 1)[1].split("\n## ", 1)[0]
    rows = [line.split(" | ") for line in text.splitlines() if line.startswith("| `")]
    return {re.findall(r"`\[*(\w+)\]*`", row[0])[0]: set(re.findall(r"`(\w+)`", row[1])) for row in rows}


def test_the_docs_have_an_example() -> None:
    assert EXAMPLES


@pytest.mark.parametrize("example", EXAMPLES)
def test_every_example_in_the_docs_loads_as_written(example: str, tmp_path: Path) -> None:
    path = tmp_path / "example.toml"
    path.write_text(example)
    scenario = load_scenario(path)
    assert scenario.name and scenario.assertions


def test_the_docs_give_every_field_of_a_scenario_file_and_every_use() -> None:
    fields = {f.removesuffix("_") for f in ScenarioFile.__dataclass_fields__}  # assert_: `assert`
    assert set(table_of("A scenario file")) == fields
    text = DOC.read_text().split("## A scenario file\n", 1)[1].split("\n## ", 1)[0]
    assert re.findall(r"^- `([\w-]+)`:", text, re.MULTILINE) == list(USES)


def test_the_docs_list_every_event_kind_with_its_fields() -> None:
    table = table_of("Events")
    assert list(table) == list(EVENTS)
    for action, kind in EVENTS.items():
        assert set(event_fields(kind)) - set(COMMON) <= table[action], action


def test_the_docs_list_every_assertion_kind_with_its_fields() -> None:
    table = table_of("Assertions")
    assert list(table) == list(CHECKS)
    for name, check in CHECKS.items():
        fields = {f for f in fields_of(check).__dataclass_fields__}
        assert fields <= table[name], name
