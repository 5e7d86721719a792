"""One stage per impairment. A stage takes a packet stamped with the time it reaches the
stage and returns the packets that leave it, each stamped with the time it leaves; it
never adds a delay that an earlier stage already applied. `STAGES` registers them by name
in pipeline order; `Pipeline` runs a packet through them."""

from typing import Any

import numpy as np

from abyss.config.linkprofile import LinkProfile
from abyss.linkemu.stages.base import Packet, Stage
from abyss.linkemu.stages.corrupt import Corrupt
from abyss.linkemu.stages.delay import Delay
from abyss.linkemu.stages.duplicate import Duplicate
from abyss.linkemu.stages.loss import Loss
from abyss.linkemu.stages.outage import Outage
from abyss.linkemu.stages.serialise import Serialise

STAGES: dict[str, type[Stage]] = {
    "duplicate": Duplicate,
    "serialise": Serialise,
    "outage": Outage,
    "loss": Loss,
    "corrupt": Corrupt,
    "delay": Delay,
}


class Pipeline:
    """The stages in order, counting what each one swallows."""

    def __init__(self, profile: LinkProfile, rng: np.random.Generator, counters: dict[str, int]):
        self.stages: list[Stage] = [cls(profile, rng) for cls in STAGES.values()]
        self.counters = counters

    def configure(self, profile: LinkProfile) -> None:
        for stage in self.stages:
            stage.configure(profile)

    def stage(self, kind: type[Stage]) -> Any:
        return next(s for s in self.stages if isinstance(s, kind))

    def run(self, packet: Packet) -> list[Packet]:
        packets = [packet]
        for stage in self.stages:
            out: list[Packet] = []
            for p in packets:
                passed = stage.process(p)
                if not passed and stage.drops:
                    self.counters[stage.drops] += 1
                out.extend(passed)
            if len(out) > len(packets):
                self.counters["duplicates"] += len(out) - len(packets)
            packets = out
        return packets


__all__ = [
    "STAGES",
    "Corrupt",
    "Delay",
    "Duplicate",
    "Loss",
    "Outage",
    "Packet",
    "Pipeline",
    "Serialise",
    "Stage",
]
