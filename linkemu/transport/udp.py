from __future__ import annotations

from typing import TYPE_CHECKING

from linkemu.stages import Packet, Serialise

if TYPE_CHECKING:
    from linkemu.link import Link


class Udp:
    """Datagrams: packets go straight onto the link; a message with a lost or corrupt
    packet is lost; duplicates and reordering reach the receiver as they happen."""

    def __init__(self, link: Link) -> None:
        self.link = link
        self.serialiser: Serialise = link.pipeline.stage(Serialise)

    def has_room(self, now_s: float, packets: int) -> bool:
        return self.serialiser.backlog(now_s) + packets <= self.link.profile.queue_limit_packets

    def send(self, now_s: float, packets: list[Packet]) -> None:
        message = self.link._messages[packets[0].message]
        for packet in packets:
            for copy in self.link.transmit(now_s, packet):
                message.pending += 1
                self.link.schedule(copy.t_s, lambda t, c=copy: self._arrive(t, c))
        if message.pending == 0:
            self.link.finish_message(packets[0].message)

    def _arrive(self, t_s: float, packet: Packet) -> None:
        message = self.link._messages.get(packet.message)
        if message is None:
            return
        if self.link.checksum_ok(packet):
            self.link.receive_part(t_s, packet)
        message.pending -= 1
        if message.pending == 0:
            self.link.finish_message(packet.message)

    def gauges(self) -> dict[str, float]:
        return {}
