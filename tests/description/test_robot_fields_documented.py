"""docs/vehicle.md lists every field of robot.toml: each one the readers take (the typed sections'
fields, the marine sections', the published figures) is in its table, by its dotted name (a row may
name a section's siblings `.name` after the first), so that a newcomer writes a package from the
page alone."""

from __future__ import annotations

import dataclasses
import json
import re
import shutil
import tomllib
import typing
from pathlib import Path

import numpy as np
import pytest

from abyss.description.marine import MARINE_FIELDS
from abyss.description.robot import ROBOTS_DIR, robot_at
from abyss.description.robot_file import PUBLISHED_FIGURES, RobotFile

DOC = Path(__file__).resolve().parents[2] / "docs" / "vehicle.md"
UNTYPED = {"added_mass", "damping", "buoyancy", "published", "config"}  # dicts the readers check
MISSING = object()


def fields(cls: type, prefix: str = "") -> list[str]:
    """Every field's dotted name: a section's (a dataclass) by its fields, the rest by its own."""
    names = []
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        kind = hints[f.name]
        if dataclasses.is_dataclass(kind) and not prefix.startswith("model."):
            names += fields(kind, f"{prefix}{f.name}.")
        elif f.name not in UNTYPED:
            names.append(f"{prefix}{f.name}")
    return names


def test_every_field_of_robot_toml_is_in_the_docs_table() -> None:
    rows = [line for line in DOC.read_text().splitlines() if line.startswith("| `")]
    expected = [
        *fields(RobotFile),
        *(f"{section}.{name}" for section, table in MARINE_FIELDS.items() for name in table),
        "published.source",
        *(f"published.{name}" for name in PUBLISHED_FIGURES),
        "config",
    ]
    assert "arm.gripper.opening_m" in expected and "sonar.site" in expected  # the walk reaches them

    def documented(name: str) -> bool:
        section, _, last = name.rpartition(".")
        return any(
            f"`{name}`" in row or (section and f"`{section}." in row and f"`.{last}`" in row) for row in rows
        )

    missing = [name for name in expected if not documented(name)]
    assert not missing, f"docs/vehicle.md's robot.toml table lacks {missing}"


def documented_fields() -> list[str]:
    """The dotted names docs/vehicle.md's robot.toml table gives, in its order: each row's
    backticked names, a sibling `.name` completed with the section of the row's first."""
    table = DOC.read_text().split("| field | what it holds | default |", 1)[1]
    names: list[str] = []
    for row in table.split("\n\n", 1)[0].splitlines()[2:]:
        section = ""
        for name in re.findall(r"`([a-z0-9_.]+)`", row.split("|")[1]):
            if name.startswith("."):
                name = section + name
            section = name.rpartition(".")[0]
            names.append(name)
    return names


@pytest.mark.parametrize("robot", ["bluerov2_heavy_alpha5", "workclass"])
def test_a_package_written_from_the_docs_table_alone_loads_as_the_shipped_one(
    tmp_path: Path, robot: str
) -> None:
    """A newcomer's robot.toml: only the fields the table names, each at the path the table gives
    it, with the shipped package's values, beside its model. It loads (a field the readers need
    that the table does not name would be missing; one the table names wrongly would be refused
    or lost) and is the shipped robot."""
    shipped_dir = ROBOTS_DIR / robot
    shipped = tomllib.loads((shipped_dir / "robot.toml").read_text())
    written: dict[str, object] = {}
    for name in documented_fields():
        value: object = shipped
        for key in name.split("."):
            value = value.get(key, MISSING) if isinstance(value, dict) else MISSING
        if value is MISSING:
            continue  # a field this package leaves to its default, or a URDF's alone
        *sections, last = name.split(".")
        table = written
        for key in sections:
            table = table.setdefault(key, {})  # type: ignore[assignment]
        table[last] = value
    package = tmp_path / robot
    shutil.copytree(shipped_dir, package)
    (package / "robot.toml").write_text(toml(written))
    mine, theirs = robot_at(str(package)), robot_at(str(shipped_dir))
    assert written["name"] == shipped["name"] and {"thrusters", "buoyancy", "config"} <= set(written)
    assert mine.spec == theirs.spec and mine.mass_kg == theirs.mass_kg
    for field in dataclasses.fields(vehicle := mine.marine):
        assert np.array_equal(getattr(vehicle, field.name), getattr(theirs.marine, field.name))


def toml(table: dict[str, object], path: str = "") -> str:
    """A table as TOML: its values, then its sub-tables under their headers."""
    values = [f"{key} = {toml_value(v)}" for key, v in table.items() if not isinstance(v, dict)]
    lines = ([f"[{path}]"] if path else []) + values
    for key, value in table.items():
        if isinstance(value, dict):
            lines.append(toml(value, f"{path}.{key}" if path else key))
    return "\n".join(lines) + "\n"


def toml_value(value: object) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, list):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    return json.dumps(value) if isinstance(value, str) else repr(value)
