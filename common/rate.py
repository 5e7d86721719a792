"""Keep a loop's period without drifting; a stop event interrupts the wait."""

from __future__ import annotations

import threading
import time


class Rate:
    def __init__(self, period_s: float, stop: threading.Event) -> None:
        self.period_s = period_s
        self.stop = stop
        self.ticks = 0
        self.missed = 0  # ticks whose work overran the deadline
        self._next_s = time.monotonic()

    def sleep(self) -> bool:
        """Wait for the next tick; False once the stop event is set. A loop that fell
        behind by more than a period starts afresh instead of bursting to catch up."""
        self._next_s += self.period_s
        now_s = time.monotonic()
        self.ticks += 1
        if now_s > self._next_s:
            self.missed += 1
        if self._next_s < now_s - self.period_s:
            self._next_s = now_s
        return not self.stop.wait(max(0.0, self._next_s - now_s))

    @property
    def deadlines_met(self) -> float:
        """Share of ticks whose work finished within the period."""
        return 1.0 - self.missed / self.ticks if self.ticks else 1.0
