from __future__ import annotations

from abyss.linkemu.stages.base import Packet, Stage


class Corrupt(Stage):
    """Flip one random bit of the packet's payload; the receiver's checksum sees it."""

    def process(self, packet: Packet) -> list[Packet]:
        if self.profile.corrupt > 0.0 and packet.data and self.rng.random() < self.profile.corrupt:
            bit = int(self.rng.integers(len(packet.data) * 8))
            flipped = bytearray(packet.data)
            flipped[bit // 8] ^= 1 << (bit % 8)
            packet.data = bytes(flipped)
            packet.corrupt = True
        return [packet]
