"""Drive a Link with made-up times, no Zenoh and no clock."""

from __future__ import annotations

import math

from abyss.linkemu.link import Delivery, Link, Offer


def drive(link: Link, offers: list[tuple[float, bytes]], block: bool = True) -> list[Delivery]:
    """Offer each payload at its time (waiting for room when the queue is full), then run
    the link until it is idle; return every delivery in delivery order."""
    out: list[Delivery] = []
    now_s = 0.0
    for t_s, payload in offers:
        now_s = max(now_s, t_s)
        while True:
            out += link.advance(now_s)
            if link.offer(now_s, payload, block=block) is not Offer.FULL:
                break
            next_s = link.next_event_s()
            assert next_s is not None, "queue full with nothing in flight"
            now_s = max(now_s, next_s)
    while (next_s := link.next_event_s()) is not None:
        out += link.advance(max(now_s, next_s) if math.isfinite(next_s) else now_s)
    return out


def numbered(n: int, size: int = 100, gap_s: float = 0.0) -> list[tuple[float, bytes]]:
    """n payloads of `size` bytes, numbered in their first 4 bytes, `gap_s` apart."""
    return [(i * gap_s, i.to_bytes(4, "big") + bytes(size - 4)) for i in range(n)]


def ids(deliveries: list[Delivery]) -> list[int]:
    return [int.from_bytes(d.payload[:4], "big") for d in deliveries]
