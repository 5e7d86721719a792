"""The simulation's faults, one row each: the table that the message's choices and docstring, the
key table's note, `abyss fault` and the Faults section of docs/commands.md are generated from.

A row names the kind of part its fault targets (thrusters, cameras, ...), never the parts: which
names those are comes from the robot's model when asked (`ModelNames`), so that a robot whose parts
are named otherwise gets faults on its own parts. The simulation's side of each fault (what it does
to the world) is stations/simulation/faults.py; a new fault is one row here and one entry there.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING

from abyss.common.errors import BadInput

if TYPE_CHECKING:
    from abyss.description.models.panel import Panel
    from abyss.description.robot_file import RobotFile

VALUE_MAX = 100.0  # a fault's value lies in [0, VALUE_MAX] whatever its row (the message's bound)


@dataclass(frozen=True)
class ModelNames:
    """The names a robot's model gives the parts a fault may target, by kind."""

    thrusters: tuple[str, ...]
    cameras: tuple[str, ...]
    nav_sensors: tuple[str, ...]  # the navigation sensors
    panel_parts: tuple[str, ...]  # the panel's valves, then its levers


TARGET_KINDS = tuple(f.name for f in fields(ModelNames))
KIND_WORDS = {  # how the docs and the help name one target of each kind, and its placeholder
    "thrusters": ("a thruster", "THRUSTER"),
    "cameras": ("a camera", "CAMERA"),
    "nav_sensors": ("a navigation sensor", "SENSOR"),
    "panel_parts": ("a valve or lever of the panel", "PART"),
}


def model_names(robot: RobotFile, panel: Panel) -> ModelNames:
    """The names of the parts of the robot `robot.toml` describes (description.robot_file) and of
    the panel's (its site's: description.site)."""
    return ModelNames(robot.thrusters.names, robot.cameras.names, robot.nav_sensors.names, panel.part_names)


@dataclass(frozen=True)
class Fault:
    """One fault: its name, the kind of part it targets (a field of ModelNames; "" for none), what
    its value means and the range it must lie in, and a line saying what it does."""

    name: str
    targets: str
    value: str  # what the value is ("efficiency", "0: off, 1: on"); "" for none (it is ignored)
    value_lo: float
    value_hi: float
    doc: str

    def __post_init__(self) -> None:
        if not self.name.isidentifier():
            raise BadInput(f"fault name {self.name!r} is not a plain word")
        if self.targets and self.targets not in TARGET_KINDS:
            kinds = ", ".join(TARGET_KINDS)
            raise BadInput(f"fault {self.name}: targets {self.targets!r} not one of {kinds}")
        if not 0.0 <= self.value_lo <= self.value_hi <= VALUE_MAX:
            raise BadInput(f"fault {self.name}: value range not within [0, {VALUE_MAX:g}]")

    def line(self) -> str:
        """`name TARGET VALUE: doc`, as the docstring and the help list it."""
        target = f" {KIND_WORDS[self.targets][1]}" if self.targets else ""
        return f"{self.name}{target}{' VALUE' if self.value else ''}: {self.doc}"

    def value_range(self) -> str:
        """The value's range and what it is ("[0, 1] (efficiency)"); "ignored" for a fault without one."""
        return f"[{self.value_lo:g}, {self.value_hi:g}] ({self.value})" if self.value else "ignored"


FAULT_TABLE: dict[str, Fault] = {
    f.name: f
    for f in (
        Fault(
            "thruster", "thrusters", "efficiency", 0.0, 1.0,
            "that thruster's efficiency (0: failed, 0.5: weakened, 1: healthy)",
        ),
        Fault("camera", "cameras", "0: off, 1: on", 0.0, 1.0, "0 blacks the camera out, 1 restores it"),
        Fault(
            "noise", "nav_sensors", "noise scale", 0.0, VALUE_MAX,
            "that navigation sensor's noise scale (1 is nominal)",
        ),
        Fault(
            "seize", "panel_parts", "1: seized, 0: freed", 0.0, 1.0,
            "1 seizes that valve or lever where it stands (it turns no further), 0 frees it",
        ),
        Fault("clear", "", "", 0.0, VALUE_MAX, "undo all"),
    )
}  # fmt: skip


class FaultNames:
    """The table's names in order, read at each use (a row registered later is among them): the
    message's choices."""

    def __contains__(self, name: object) -> bool:
        return name in FAULT_TABLE

    def __iter__(self) -> Iterator[str]:
        return iter(tuple(FAULT_TABLE))

    def __len__(self) -> int:
        return len(FAULT_TABLE)

    def __repr__(self) -> str:
        return repr(tuple(FAULT_TABLE))


NAMES = FaultNames()


def fault_names() -> tuple[str, ...]:
    """The table's names, in order, now."""
    return tuple(FAULT_TABLE)


def register(fault: Fault) -> Fault:
    """Add a row to the table (after the others); refuses a name already there."""
    if fault.name in FAULT_TABLE:
        raise BadInput(f"fault {fault.name!r} is already in the table")
    FAULT_TABLE[fault.name] = fault
    return fault


def row(name: str) -> Fault:
    """The table's row of fault `name`; BadInput naming the faults for an unknown one."""
    if name not in FAULT_TABLE:
        raise BadInput(f"fault {name!r} not one of {', '.join(FAULT_TABLE)}")
    return FAULT_TABLE[name]


def targets(name: str, names: ModelNames) -> tuple[str, ...]:
    """The parts fault `name` may target on the model that `names` are of; () for a fault that
    targets nothing. The one lookup of targets: the simulation and `abyss fault` both ask it."""
    kind = row(name).targets
    return getattr(names, kind) if kind else ()


def check(name: str, target: str, value: float, names: ModelNames) -> Fault:
    """Fault `name`'s row, with `target` one of its targets on the model and `value` in its range;
    BadInput naming the allowed targets, or the range, otherwise. A fault that targets nothing
    takes any target (it is ignored)."""
    fault = row(name)
    allowed = targets(name, names)
    if fault.targets and target not in allowed:
        raise BadInput(f"{name} target {target!r} not one of {', '.join(allowed)}")
    if not fault.value_lo <= value <= fault.value_hi:
        raise BadInput(f"{name} value {value:g} not in {fault.value_range()}")
    return fault


def doc_lines() -> str:
    """One line per fault (`Fault.line`), as SimulationControl's docstring lists them."""
    return "\n".join(f.line() for f in FAULT_TABLE.values())


def key_note() -> str:
    """The key table's note on the simulation's control key."""
    return f"faults: {', '.join(FAULT_TABLE)}"


def faults_table() -> str:
    """The Markdown table of the faults; docs/commands.md holds it."""
    rows = ["| fault | target | value | what it does |", "| --- | --- | --- | --- |"]
    for f in FAULT_TABLE.values():
        target = KIND_WORDS[f.targets][0] if f.targets else "none"
        rows.append(f"| `{f.name}` | {target} | {f.value_range()} | {f.doc} |")
    return "\n".join(rows)
