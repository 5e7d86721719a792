"""`Latest`: the value a station's threads share, set by one and read by the others."""

from __future__ import annotations

import threading

from abyss.common.shared import Latest


def test_latest_gives_the_initial_value_then_each_set() -> None:
    latest: Latest[float | None] = Latest(None)
    assert latest.get() is None
    latest.set(1.5)
    assert latest.get() == 1.5


def test_update_never_loses_a_step_between_threads() -> None:
    count = Latest(0)

    def add() -> None:
        for _ in range(2000):
            count.update(1, lambda old, step: old + step)

    threads = [threading.Thread(target=add) for _ in range(4)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=30)
    assert count.get() == 8000


def test_update_with_max_keeps_a_clock_from_going_back() -> None:
    clock_s = Latest(0.0)
    assert clock_s.update(2.0, max) == 2.0
    assert clock_s.update(1.0, max) == 2.0
