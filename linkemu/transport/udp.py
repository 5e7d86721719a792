from __future__ import annotations

import functools
from typing import TYPE_CHECKING

from abyss.linkemu.stages import Packet, Serialise

if TYPE_CHECKING:
    from abyss.linkemu.transport.base import Wire


class Udp:
    """Datagrams: packets go straight onto the link; a message with a lost or corrupt
    packet is lost; duplicates and reordering reach the receiver as they happen."""

    def __init__(self, link: Wire) -> None:
        self.link = link
        self.serialiser: Serialise = link.pipeline.stage(Serialise)
        self.travelling: dict[int, int] = {}  # message id -> packet copies still on the wire

    def has_room(self, now_s: float, packets: int) -> bool:
        return self.serialiser.backlog(now_s) + packets <= self.link.profile.queue_limit_packets

    def room_s(self, now_s: float, packets: int) -> float | None:
        return self.serialiser.room_s(now_s, packets)

    def send(self, now_s: float, packets: list[Packet]) -> None:
        mid = packets[0].message
        copies = [copy for packet in packets for copy in self.link.transmit(now_s, packet)]
        if not copies:
            self.link.finish_message(mid)
            return
        self.travelling[mid] = len(copies)
        for copy in copies:
            self.link.schedule(copy.t_s, functools.partial(self._arrive, packet=copy))

    def _arrive(self, t_s: float, packet: Packet) -> None:
        if self.link.checksum_ok(packet):
            self.link.receive_part(t_s, packet)
        self.travelling[packet.message] -= 1
        if self.travelling[packet.message] == 0:
            del self.travelling[packet.message]
            self.link.finish_message(packet.message)

    def gauges(self) -> dict[str, float]:
        return {}
