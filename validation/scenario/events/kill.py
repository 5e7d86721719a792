from __future__ import annotations

import os
import signal
from dataclasses import dataclass
from typing import Annotated

from abyss.common.reading import OneOf
from abyss.interface import keys
from abyss.validation.scenario.events.base import Context, Event


@dataclass(frozen=True, kw_only=True)
class Kill(Event):
    """A station's computer dies (SIGKILL); with the scenario's `restart`, abyss up starts it
    again, else the run ends, as it would for a crash."""

    station: Annotated[str, OneOf(keys.STATIONS)]

    def describe(self) -> str:
        return f"kill {self.station}"

    def apply(self, ctx: Context) -> str:
        ctx.killed += 1
        if ctx.holds is not None:
            ctx.boots[self.station] = ctx.holds.boot(self.station)
        state = ctx.up.state()
        pid = state.stations[self.station].pid if state and self.station in state.stations else None
        if pid is None:
            return f"kill {self.station}: no pid (an external station?)"
        os.kill(pid, signal.SIGKILL)
        return self.describe()

    def settled(self, ctx: Context) -> str:
        """Restarted: until it is back (the simulation resumes on this period and holds again);
        not restarted, abyss up ends the run, as in real time."""
        if not ctx.restart:
            return ""
        holds, boot = ctx.held(), ctx.boots.get(self.station, 0) + 1
        if self.station == "simulation":
            holds.held(ctx.t_s, boot, ctx.up.running, ctx.timeout_s)
        else:
            ctx.wait(
                f"{self.station} restarted", lambda: holds.reported(self.station, "ready", boot) is not None
            )
        return ", restarted"
