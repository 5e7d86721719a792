"""What `abyss robot check` finds: a row per check (its figures, the bound, pass or warn, why) and
the whole report, which check.py fills and plot.py draws."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from abyss.validation.robot import physics
from abyss.validation.robot.geometry import AxisLimit, Workspace

Status = Literal["pass", "warn", "n/a"]
CHECKS = ("kinematics", "hydrostatics", "allocation", "open loop", "published", "workspace")


@dataclass(frozen=True)
class Row:
    check: str  # one of CHECKS
    name: str
    figures: str  # with their units
    bound: str  # what is expected
    status: Status
    why: str  # one line


@dataclass(frozen=True)
class Report:
    robot: str
    directory: Path
    rows: tuple[Row, ...]
    hydrostatics: physics.Hydrostatics
    limits: tuple[AxisLimit, ...]
    responses: tuple[physics.Response, ...]
    decays: tuple[physics.Decay, ...]
    workspace: Workspace
    runtime_s: float

    @property
    def passed(self) -> bool:
        return all(r.status != "warn" for r in self.rows)

    def text(self) -> str:
        """The table, one row a line, then the tally."""
        head = ("check", "row", "figures", "bound", "result", "why")
        cells = [head] + [(r.check, r.name, r.figures, r.bound, r.status, r.why) for r in self.rows]
        widths = [max(len(c[i]) for c in cells) for i in range(5)]
        lines = [f"abyss robot check: {self.robot} ({self.directory})"]
        lines += ["  ".join(c[i].ljust(widths[i]) for i in range(5)) + "  " + c[5] for c in cells]
        warned = sum(r.status == "warn" for r in self.rows)
        verdict = "every check passes" if not warned else f"{warned} row(s) warn"
        lines.append(f"{verdict}; {len(self.rows)} rows in {self.runtime_s:.1f} s")
        return "\n".join(lines)
