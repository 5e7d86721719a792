"""docs/vehicle.md lists every field of robot.toml: each one the readers take (the typed sections'
fields, the marine sections', the published figures) is in its table, by its dotted name (a row may
name a section's siblings `.name` after the first), so that a newcomer writes a package from the
page alone."""

from __future__ import annotations

import dataclasses
import typing
from pathlib import Path

from abyss.common.robot import PUBLISHED_FIGURES, RobotFile
from abyss.stations.simulation.hydrodynamics import MARINE_FIELDS

DOC = Path(__file__).resolve().parents[2] / "docs" / "vehicle.md"
UNTYPED = {"added_mass", "damping", "buoyancy", "published", "config"}  # dicts the readers check


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
