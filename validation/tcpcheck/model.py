"""The TCP comparison's model side: a phase through `Link` (transport tcp) with made-up times."""

from __future__ import annotations

import math

from abyss.common.errors import LinkError
from abyss.linkemu.link import Link, Offer
from abyss.validation.tcpcheck.workload import Case, Phase, Run


def run_model(case: Case, phase: Phase, seed: int) -> Run:
    """The phase through `Link` (transport tcp) with made-up times: each message offered when it
    is due, or as soon as the sender's queue has room (and before the window ends)."""
    link = Link(case.link_profile(seed))
    end_s = phase.window_s if phase.window_s is not None else math.inf
    deliveries: list[tuple[float, int, float]] = []
    now_s = 0.0

    def run_until(t_s: float) -> None:
        nonlocal now_s
        now_s = max(now_s, t_s)
        deliveries.extend((d.tag[0], d.tag[1], d.delivered_s) for d in link.advance(now_s))

    for due_s, size in phase.schedule:
        run_until(due_s)
        while now_s < end_s and link.offer(now_s, bytes(size), block=True, tag=(due_s, size)) is Offer.FULL:
            next_s = link.next_event_s()
            if next_s is None:
                raise LinkError(f"{case.name} {phase.name}: the model's queue is full with nothing in flight")
            run_until(min(next_s, end_s))
    while now_s < end_s and (next_s := link.next_event_s()) is not None:
        run_until(min(next_s, end_s))
    retransmissions = link.counters["retransmissions"]
    return Run(
        phase,
        deliveries,
        link.counters["packets_sent"] - retransmissions,
        retransmissions,
        link.counters["timeouts"],
        {"losses": link.counters["losses"], "queue_drops": link.counters["queue_drops"]},
    )
