"""Keep a loop's period without drifting, on the system's clock; a stop event interrupts the wait."""

from __future__ import annotations

import threading

from abyss.timing.clock import WALL, Clock


class Rate:
    """A loop's ticks every `period_s` of `clock` (the wall clock, or simulated time). A loop with a
    `name` tells its clock, each time it waits, the time of its next tick: it needs nothing before
    then (with simulated time, the simulation waits for the slowest loop)."""

    def __init__(self, period_s: float, stop: threading.Event, clock: Clock = WALL, name: str = "") -> None:
        self.period_s = period_s
        self.stop = stop
        self.clock = clock
        self.name = name
        self.ticks = 0
        self.missed = 0  # ticks whose work overran the deadline
        self.late = False  # the last one did
        self._next_s = clock.now_s()
        if name:
            clock.enter(name, self._next_s, stop)

    def sleep(self) -> bool:
        """Wait for the next tick; False once the stop event is set. A loop that fell
        behind by more than a period starts afresh instead of bursting to catch up."""
        self._next_s += self.period_s
        now_s = self.clock.now_s()
        self.ticks += 1
        self.late = now_s > self._next_s and self.period_s > 0
        self.missed += self.late
        if self._next_s < now_s - self.period_s:
            self._next_s = now_s
        if self.name:
            return self.clock.sleep_until(self.name, self._next_s, self.stop)
        return not self.clock.wait_until(self.stop, self._next_s)

    def forgive(self) -> None:
        """What the loop waited for since its tick (the simulation held back for a station) is not
        its lateness: its next tick counts from now."""
        self._next_s = max(self._next_s, self.clock.now_s())

    @property
    def deadlines_met(self) -> float:
        """Share of ticks whose work finished within the period."""
        return 1.0 - self.missed / self.ticks if self.ticks else 1.0
