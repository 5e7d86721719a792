from __future__ import annotations

from abyss.linkemu.stages.base import Packet, Stage


class Duplicate(Stage):
    """Send a packet twice; the copy takes its own place in the queue."""

    def process(self, packet: Packet) -> list[Packet]:
        if self.profile.duplicate > 0.0 and self.rng.random() < self.profile.duplicate:
            return [packet, packet.copy()]
        return [packet]
