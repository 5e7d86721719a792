from __future__ import annotations

import bisect
import math
from collections import deque
from typing import Any

from abyss.config.linkprofile import LinkProfile, load_trace
from abyss.linkemu.stages.base import Packet, Stage

OPPORTUNITY_BYTES = 1500  # what one line of a delivery trace carries (mahimahi's MTU)


class Serialise(Stage):
    """The bottleneck: packets leave one after another at the link rate, or at the delivery
    opportunities of the profile's trace (mahimahi's mm-link: each line of it, 1500 bytes, the
    trace repeating from the hop's first packet; an opportunity that finds no packet waiting
    goes unused); a queue of `queue_limit_packets` (waiting or being sent) drops at the tail
    when full."""

    drops = "queue_drops"

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.busy_until_s = 0.0
        self._ends_s: deque[float] = deque()  # serialisation end of each queued packet
        self.trace: tuple[float, ...] | None = None
        self.origin_s: float | None = None  # when the trace started: the hop's first packet
        self.k, self.left_bytes = 0, OPPORTUNITY_BYTES  # the opportunity in use, what it has left
        super().__init__(*args, **kwargs)

    def configure(self, profile: LinkProfile) -> None:
        super().configure(profile)
        trace = load_trace(profile.trace) if profile.trace else None
        if trace != self.trace:  # a new trace starts at the next packet
            self.trace, self.origin_s, self.k, self.left_bytes = trace, None, 0, OPPORTUNITY_BYTES

    def backlog(self, now_s: float) -> int:
        """Packets queued or on the wire at `now_s`."""
        while self._ends_s and self._ends_s[0] <= now_s:
            self._ends_s.popleft()
        return len(self._ends_s)

    def room_s(self, now_s: float, packets: int) -> float:
        """When `packets` more fit in the queue: now, or the end of the packet whose leaving
        makes the room (the queue drains only as the link serialises)."""
        over = self.backlog(now_s) + packets - self.profile.queue_limit_packets
        return now_s if over <= 0 else self._ends_s[over - 1]

    def process(self, packet: Packet) -> list[Packet]:
        if self.trace is None and math.isinf(self.profile.rate_bps):
            return [packet]
        if self.backlog(packet.t_s) >= self.profile.queue_limit_packets:
            return []
        start_s = max(packet.t_s, self.busy_until_s)
        if self.trace is None:
            self.busy_until_s = start_s + packet.size_bytes * 8.0 / self.profile.rate_bps
        else:
            self.busy_until_s = self._by_trace(start_s, packet.size_bytes)
        self._ends_s.append(self.busy_until_s)
        packet.t_s = self.busy_until_s
        return [packet]

    def _at(self, k: int) -> float:
        assert self.trace is not None and self.origin_s is not None
        return self.origin_s + (k // len(self.trace)) * self.trace[-1] + self.trace[k % len(self.trace)]

    def _by_trace(self, start_s: float, size_bytes: int) -> float:
        """When a packet at the head of the queue from `start_s` has had its bytes delivered."""
        assert self.trace is not None
        if self.origin_s is None:
            self.origin_s = start_s
        if self._at(self.k) < start_s:  # the opportunities since went unused: the first one from now
            loops, into_s = divmod(start_s - self.origin_s, self.trace[-1])
            self.k = int(loops) * len(self.trace) + bisect.bisect_left(self.trace, into_s)
            self.k += self._at(self.k) < start_s  # rounding at the edge
            self.left_bytes = OPPORTUNITY_BYTES
        while size_bytes > self.left_bytes:
            size_bytes -= self.left_bytes
            self.k, self.left_bytes = self.k + 1, OPPORTUNITY_BYTES
        self.left_bytes -= size_bytes
        return self._at(self.k)
