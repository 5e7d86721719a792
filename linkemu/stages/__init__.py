"""One stage per impairment. A stage takes a packet stamped with the time it reaches the
stage and returns the packets that leave it, each stamped with the time it leaves; it
never adds a delay that an earlier stage already applied. `STAGES` registers them by name
in pipeline order."""

from linkemu.stages.base import Packet, Stage
from linkemu.stages.corrupt import Corrupt
from linkemu.stages.delay import Delay
from linkemu.stages.duplicate import Duplicate
from linkemu.stages.loss import Loss
from linkemu.stages.serialise import Serialise

STAGES: dict[str, type[Stage]] = {
    "duplicate": Duplicate,
    "serialise": Serialise,
    "loss": Loss,
    "corrupt": Corrupt,
    "delay": Delay,
}

__all__ = ["STAGES", "Corrupt", "Delay", "Duplicate", "Loss", "Packet", "Serialise", "Stage"]
