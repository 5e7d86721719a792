from __future__ import annotations

import math
from collections import deque

from abyss.linkemu.stages.base import Packet, Stage


class Serialise(Stage):
    """The bottleneck: packets leave one after another at the link rate; a queue of
    `queue_limit_packets` (waiting or being sent) drops at the tail when full."""

    drops = "queue_drops"

    def __init__(self, *args, **kwargs) -> None:  # type: ignore[no-untyped-def]
        self.busy_until_s = 0.0
        self._ends_s: deque[float] = deque()  # serialisation end of each queued packet
        super().__init__(*args, **kwargs)

    def backlog(self, now_s: float) -> int:
        """Packets queued or on the wire at `now_s`."""
        while self._ends_s and self._ends_s[0] <= now_s:
            self._ends_s.popleft()
        return len(self._ends_s)

    def process(self, packet: Packet) -> list[Packet]:
        if math.isinf(self.profile.rate_bps):
            return [packet]
        if self.backlog(packet.t_s) >= self.profile.queue_limit_packets:
            return []
        start_s = max(packet.t_s, self.busy_until_s)
        self.busy_until_s = start_s + packet.size_bytes * 8.0 / self.profile.rate_bps
        self._ends_s.append(self.busy_until_s)
        packet.t_s = self.busy_until_s
        return [packet]
