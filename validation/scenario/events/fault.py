from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Annotated

from abyss.common.reading import OneOf
from abyss.interface import keys
from abyss.interface.messages import FAULTS, SimulationControl, encode
from abyss.validation.scenario.events.base import Context, Event


@dataclass(frozen=True, kw_only=True)
class Fault(Event):
    """A fault injected into the simulation (messages.FAULTS): `target` (a thruster, a
    sensor...) and `value` as the fault takes them."""

    fault: Annotated[str, OneOf(FAULTS)]
    target: str = ""
    value: float = 0.0

    def describe(self) -> str:
        return f"fault {self.fault} {self.target} {self.value:g}".rstrip()

    def apply(self, ctx: Context) -> str:
        control = SimulationControl(self.fault, self.target, self.value)
        ctx.session.put(keys.simulation_control_key(ctx.system_id), encode(control, 0, time.time()))
        return self.describe()

    def settled(self, ctx: Context) -> str:
        """Until the simulation counts it among the controls it applied."""
        ctx.controls += 1
        holds, count = ctx.held(), ctx.controls
        ctx.wait(
            f"the simulation to apply {self.describe()}",
            lambda: (
                (r := holds.reported("simulation", "held")) is not None
                and r.delivered.get("controls", 0.0) >= count
            ),
        )
        return ""
