"""One direction of one hop: a pure, event-driven core.

A message offered at time t is cut into packets of the link MTU and handed to the
transport (`udp` or `tcp`), which pushes packets through the stage pipeline
(duplicate, serialise, loss, corrupt, delay). Every time is explicit: the caller passes
`now_s`, and `advance(now_s)` returns the messages delivered by then, each with the time
the emulated link delivered it. A test drives it with made-up times and no Zenoh; the
bus drives it with the wall clock (linkemu.runner).
"""

from __future__ import annotations

import enum
import heapq
import itertools
import math
import zlib
from collections.abc import Callable, Container
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from abyss.common.errors import LinkError
from abyss.common.samples import Samples
from abyss.config.linkprofile import LinkProfile
from abyss.linkemu.stages import Packet, Pipeline
from abyss.linkemu.transport import TRANSPORTS

HEADER_BYTES = {"tcp": 40, "udp": 28}  # IPv4 + TCP / UDP headers per packet
DELAY_SAMPLES = 4096  # delivered-message delays kept for percentiles


class Offer(enum.Enum):
    ACCEPTED = "accepted"
    DROPPED = "dropped"  # queue full and congestion control DROP, or larger than the queue
    FULL = "full"  # queue full and congestion control BLOCK: try again when there is room


@dataclass(frozen=True)
class Delivery:
    payload: bytes
    offered_s: float  # when the sender offered it
    delivered_s: float  # when the emulated link delivered it
    corrupt: bool  # carries flipped bits (only with deliver_corrupt)
    tag: Any = None


@dataclass
class _Message:
    payload_size: int
    offered_s: float
    packets: int
    tag: Any
    parts: dict[int, bytes] = field(default_factory=dict)
    copies: list[int] = field(default_factory=list)  # arrivals of each part
    deliveries: int = 0
    corrupt: bool = False


class Link:
    """One emulated link direction. Not thread-safe: the runner holds a lock around it."""

    def __init__(self, profile: LinkProfile, rng: np.random.Generator | None = None) -> None:
        self.profile = profile
        self.rng = rng if rng is not None else np.random.default_rng(profile.seed)
        self.counters: dict[str, int] = dict.fromkeys(COUNTERS, 0)
        self.pipeline = Pipeline(profile, self.rng, self.counters)
        self._events: list[tuple[float, int, Callable[[float], None]]] = []
        self._tie = itertools.count()
        self._messages: dict[int, _Message] = {}
        self._next_message = itertools.count()
        self._next_seq = itertools.count()
        self._ready: list[Delivery] = []
        self.delays_s = Samples(DELAY_SAMPLES)  # offer to delivery, of delivered messages
        self.transport = TRANSPORTS[profile.transport](self)

    # -- for callers -------------------------------------------------------------------
    def offer(self, now_s: float, payload: bytes, block: bool = False, tag: Any = None) -> Offer:
        """Offer a message at `now_s`. With `block`, FULL means: wait for room, offer again.
        `tag` comes back with its delivery."""
        self._run_events(now_s)
        n = self.packets_for(len(payload))
        if n > self.profile.queue_limit_packets:
            self.counters["messages_dropped"] += 1
            return Offer.DROPPED
        if not self.transport.has_room(now_s, n):
            if block:
                return Offer.FULL
            self.counters["messages_dropped"] += 1
            return Offer.DROPPED
        self.counters["messages_offered"] += 1
        self.counters["bytes_offered"] += len(payload)
        mid = next(self._next_message)
        self._messages[mid] = _Message(len(payload), now_s, n, tag, copies=[0] * n)
        size = self.payload_per_packet
        packets = [
            Packet(
                seq=next(self._next_seq),
                message=mid,
                index=i,
                data=part,
                crc=zlib.crc32(part),
                size_bytes=len(part) + HEADER_BYTES[self.profile.transport],
                t_s=now_s,
                last=i == n - 1,
            )
            for i, part in enumerate(payload[i * size : (i + 1) * size] for i in range(n))
        ]
        self.transport.send(now_s, packets)
        return Offer.ACCEPTED

    def advance(self, now_s: float) -> list[Delivery]:
        """Process every event up to `now_s`; return the messages delivered by then."""
        self._run_events(now_s)
        ready, self._ready = self._ready, []
        return ready

    def pass_through(self, nbytes: int) -> None:
        """Count a message that bypassed the emulation (ideal profile, netem backend)."""
        for name, value in (
            ("messages_offered", 1),
            ("messages_delivered", 1),
            ("bytes_offered", nbytes),
            ("bytes_delivered", nbytes),
        ):
            self.counters[name] += value

    def room_s(self, now_s: float, nbytes: int) -> float | None:
        """The earliest time from `now_s` a message of `nbytes` may find room in the queue (a
        sender that found it FULL offers again then; None: nothing in flight will make room)."""
        self._run_events(now_s)
        return self.transport.room_s(now_s, self.packets_for(nbytes))

    def next_timed_s(self) -> float | None:
        """The time of the next event on the link (a packet's arrival, an acknowledgement, a timer)."""
        return self._events[0][0] if self._events else None

    def next_event_s(self) -> float | None:
        if self._ready:
            return -math.inf
        return self.next_timed_s()

    def reconfigure(self, profile: LinkProfile) -> None:
        """Apply a new profile to every packet sent from now on; none in flight is lost."""
        if profile.transport != self.profile.transport:
            raise LinkError(
                f"transport is {self.profile.transport} for the life of a link; "
                f"restart the station to use {profile.transport}"
            )
        self.profile = profile
        self.pipeline.configure(profile)

    def in_flight(self, tags: Container[Any] | None = None) -> int:
        """Messages offered and neither delivered nor lost yet (of those tagged one of `tags`)."""
        if tags is None:
            return len(self._messages)
        return sum(m.tag in tags for m in self._messages.values())

    def snapshot(self) -> dict[str, float]:
        stats: dict[str, float] = {k: float(v) for k, v in self.counters.items()}
        stats.update(self.delays_s.percentiles("delay", 1e3, "ms"))
        stats["in_flight"] = float(self.in_flight())
        stats.update(self.transport.gauges())
        return stats

    # -- for transports ----------------------------------------------------------------
    @property
    def payload_per_packet(self) -> int:
        return self.profile.mtu_bytes - HEADER_BYTES[self.profile.transport]

    def packets_for(self, nbytes: int) -> int:
        return max(1, math.ceil(nbytes / self.payload_per_packet))

    def schedule(self, t_s: float, action: Callable[[float], None]) -> None:
        heapq.heappush(self._events, (t_s, next(self._tie), action))

    def transmit(self, t_s: float, packet: Packet) -> list[Packet]:
        """Put a packet on the wire at `t_s`; return the copies that will reach the receiver,
        stamped with their arrival times (none: it was dropped or lost)."""
        self.counters["packets_sent"] += 1
        packet.t_s = t_s
        return self.pipeline.run(packet)

    def checksum_ok(self, packet: Packet) -> bool:
        """The receiver's check; a corrupt packet is counted, and passed on only with
        deliver_corrupt."""
        if zlib.crc32(packet.data) == packet.crc:
            return True
        self.counters["packets_corrupted"] += 1
        if self.profile.deliver_corrupt:
            self.counters["corrupt_delivered"] += 1
            return True
        return False

    def receive_part(self, t_s: float, packet: Packet) -> None:
        """A packet's data reached the application: deliver its message each time every
        part of it has arrived once more (a fully duplicated datagram arrives twice)."""
        message = self._messages.get(packet.message)
        if message is None:
            return
        message.parts.setdefault(packet.index, packet.data)
        message.corrupt |= packet.corrupt
        message.copies[packet.index] += 1
        if min(message.copies) > message.deliveries:
            message.deliveries += 1
            payload = b"".join(message.parts[i] for i in range(message.packets))
            self._deliver(t_s, message, payload)

    def finish_message(self, message_id: int) -> None:
        """No more parts of this message will come; it is lost if it was never delivered."""
        message = self._messages.pop(message_id, None)
        if message is not None and message.deliveries == 0:
            self.counters["messages_lost"] += 1

    # -- internals ---------------------------------------------------------------------
    def _deliver(self, t_s: float, message: _Message, payload: bytes) -> None:
        self.counters["messages_delivered"] += 1
        self.counters["bytes_delivered"] += len(payload)
        self.delays_s.add(t_s - message.offered_s)
        self._ready.append(Delivery(payload, message.offered_s, t_s, message.corrupt, message.tag))

    def _run_events(self, now_s: float) -> None:
        while self._events and self._events[0][0] <= now_s:
            t_s, _, action = heapq.heappop(self._events)
            action(t_s)


COUNTERS = (
    "messages_offered",
    "messages_delivered",
    "messages_dropped",
    "messages_lost",
    "bytes_offered",
    "bytes_delivered",
    "packets_sent",
    "queue_drops",
    "losses",
    "outages",
    "packets_corrupted",
    "corrupt_delivered",
    "duplicates",
    "retransmissions",
    "timeouts",
    "undelivered_at_close",
    "refused_at_stop",
)
