"""What every scenario event shares: when it lands (`at_s`, after `phase`), and what the runner
hands it (`Context`): the bus, the system, its state and, in lockstep, the holds. An event is a
frozen dataclass whose typed fields are its table's fields; `apply` carries it out, and in
lockstep `settled` waits, the simulation held, until it took effect."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Annotated, Protocol

from abyss.common.errors import AbyssError
from abyss.common.reading import OneOf
from abyss.interface.messages import INTERVENTION_PHASES

if TYPE_CHECKING:
    import zenoh

    from abyss.launch.state import RunState
    from abyss.timing.lockstep_testbed import Holds


class Running(Protocol):
    """The system a scenario runs (runner.System)."""

    def running(self) -> bool: ...

    def state(self) -> RunState | None: ...


@dataclass
class Context:
    """What an event is carried out with; the runner makes one per run."""

    session: zenoh.Session
    system_id: str
    up: Running
    restart: bool  # the scenario starts a killed station again
    timeout_s: float  # lockstep: for an event to take effect
    holds: Holds | None = None  # lockstep only: the simulation's holds
    t_s: float = 0.0  # lockstep: the held period's simulated time [s]
    controls: int = 0  # lockstep: the simulation's controls applied so far, by its count
    boots: dict[str, int] = field(default_factory=dict)  # lockstep: a station's boot before a kill
    killed: int = 0  # stations killed on purpose

    def held(self) -> Holds:
        """The holds; AbyssError if the run is not in lockstep."""
        if self.holds is None:
            raise AbyssError("an event's settling waits on lockstep's holds: the run has none")
        return self.holds

    def wait(self, what: str, ready: Callable[[], bool]) -> None:
        """Until `ready()`, the simulation held; AbyssError naming `what` if not in time."""
        self.held().wait(what, ready, self.up.running, self.timeout_s)


@dataclass(frozen=True, kw_only=True)
class Event:
    at_s: float  # after all stations are up [s], or after onboard first reports `phase`
    # an intervention's phase (messages.INTERVENTION_PHASES), e.g. turn; "": from all up
    phase: Annotated[str, OneOf(INTERVENTION_PHASES[1:], blank=True)] = ""

    def when(self) -> str:
        return f"{self.at_s:g} s into {self.phase}" if self.phase else f"t={self.at_s:g} s"

    def describe(self) -> str:
        """What it does, in a few words (the run's log, the report)."""
        raise NotImplementedError

    def apply(self, ctx: Context) -> str:
        """Carry it out; a line saying what was done."""
        raise NotImplementedError

    def settled(self, ctx: Context) -> str:
        """Lockstep: wait until it took effect (the simulation held meanwhile); what to add to
        `apply`'s line. Nothing by default."""
        return ""
