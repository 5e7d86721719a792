"""One stage per impairment. A stage takes a packet stamped with the time it reaches the
stage and returns the packets that leave it, each stamped with the time it leaves; it
never adds a delay that an earlier stage already applied. `STAGES` registers them by name
in pipeline order."""

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

__all__ = ["STAGES", "Corrupt", "Delay", "Duplicate", "Loss", "Outage", "Packet", "Serialise", "Stage"]
