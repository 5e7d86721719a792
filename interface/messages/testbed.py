"""The testbed's messages: faults, the simulation's status and clock, lockstep, the links,
the panel's truth, replay."""

from __future__ import annotations

import textwrap
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from abyss.common.errors import BadInput
from abyss.interface import faults
from abyss.interface.messages.schema import Message, array, scalar

FAULTS = faults.fault_names()  # the fault table's names (interface/faults.py) as imported


@dataclass(frozen=True)
class SimulationControl(Message):
    """A fault injected into the simulation (scenario runner, tests): `fault` a row of the fault
    table (interface/faults.py), `target` the part it acts on, `value` its setting. The faults:"""

    fault: str = field(metadata={"choices": faults.NAMES})  # the table's names, a row registered later too
    target: str = scalar()
    value: float = scalar(0.0, faults.VALUE_MAX)


SimulationControl.__doc__ = f"{SimulationControl.__doc__}\n{textwrap.indent(faults.doc_lines(), '    ')}"


@dataclass(frozen=True)
class SimulationStatus(Message):
    """The simulation's clock against the wall clock, and the active faults; with simulated time,
    the wall seconds it waited on each station (`held_s`: the one that limited the speed)."""

    VERSION: ClassVar[int] = 2  # 2: held_s
    sim_time_s: float = scalar(0.0)
    realtime_factor: float = scalar(0.0, 1e6)
    deadlines_met: float = scalar(0.0, 1.0)  # share of control periods that kept their deadline
    faults: dict[str, float] = field(default_factory=dict)
    held_s: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class SimTime(Message):
    """Simulated time (timing.clock): the simulation's clock on `abyss/<system>/clock`, a
    station's progress (how far its loops are done) on `abyss/<system>/<station>/progress`."""

    sim_time_s: float = scalar(0.0)


# a station's: its links delivered (counts per key in this epoch), done with the period, ready
# (its loops are all there: a restarted station may be let in); the simulation's: held before a
# hold's period (`delivered`: {"controls": faults applied in the hold}); the testbed's: release
LOCKSTEP_PHASES = ("delivered", "done", "ready", "held", "release", "holds")


@dataclass(frozen=True)
class LockstepReport(Message):
    """A station's progress through a lockstep period (timing.lockstep) at `sim_time_s`: its links
    delivered what was due (`delivered`: messages per key in the epoch, since the last hold), it is
    done with the period, or ready to run its first; the simulation held at a hold, and the
    testbed's release of it; the holds the testbed added during the run (`delivered`: their
    times), and how many of them a station has (`sim_time_s`). `boot`: the sender's (0, then one
    more each restart)."""

    VERSION: ClassVar[int] = 3  # 2: boot, holds; 3: holds added during the run
    sim_time_s: float = scalar(0.0)
    phase: str = scalar(choices=LOCKSTEP_PHASES)
    delivered: dict[str, float] = field(default_factory=dict)
    boot: int = field(default=0, metadata={"lo": 0, "hi": 2**31, "choices": ()})


@dataclass(frozen=True)
class PanelState(Message):
    """The simulation's truth of the panel, for scoring only: each valve's and lever's joint
    angle [rad], and the normal force [N] of the fingers' contacts with each (0: untouched)."""

    names: tuple[str, ...] = scalar()
    angles_rad: np.ndarray = array("f8", (None,), -10.0, 10.0, max_rows=64)
    finger_force_n: np.ndarray = array("f8", (None,), 0.0, 1e6, max_rows=64)
    sim_time_s: float = scalar(0.0)

    def __post_init__(self) -> None:
        super().__post_init__()
        if not len(self.names) == len(self.angles_rad) == len(self.finger_force_n):
            raise BadInput("names, angles_rad and finger_force_n differ in length")


@dataclass(frozen=True)
class LinkControl(Message):
    """A change of a hop's profile: a named profile, then field overrides ('20mbit', '5%')."""

    profile: str = ""
    overrides: dict[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class LinkStats(Message):
    """What one emulated link direction measured."""

    hop: str = ""
    direction: str = ""  # "<sender>-><receiver>"
    profile: str = ""
    fields: dict[str, str] = field(default_factory=dict)  # the profile as written
    stats: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class ReplayStart(Message):
    """When the replayed stations begin (`abyss replay`): the recorded run's first message is
    published again at `start_s` (wall clock [s]), the rest at their recorded times after it."""

    start_s: float = scalar(0.0)
