"""Load shedding as an inbox counts it: a queue the station drains counts the oldest messages
newer ones pushed out before it came back; an inbox read only for its latest message sheds
nothing (it is meant to hold one)."""

from __future__ import annotations

from abyss.bus.session import Inbox
from abyss.interface.messages import Heartbeat, Received


def item(seq: int) -> Received:
    return Received("k", Heartbeat(shore_silence_s=0.0), seq, 0.0)


def test_a_drained_queue_counts_what_overflow_pushed_out_and_a_latest_reader_does_not() -> None:
    queue, latest = Inbox(maxlen=3), Inbox(maxlen=3)
    assert queue.drain() == []  # the station drains it: a queue
    for seq in range(5):
        queue.put(item(seq))
        latest.put(item(seq))
    assert [r.seq for r in queue.drain()] == [2, 3, 4] and queue.shed == 2
    assert latest.latest() is not None and latest.latest().seq == 4 and latest.shed == 0  # type: ignore[union-attr]
    queue.put(item(5))
    assert [r.seq for r in queue.drain()] == [5] and queue.shed == 2
