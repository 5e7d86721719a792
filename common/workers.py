"""A station's threads as one group, the way trio's nurseries hold tasks: each worker runs until
the station's stop event is set; the first worker to raise sets it for all, and its exception
reaches the station's exit code when the group closes instead of dying silently in a thread.
Closing never waits longer than `join_s` in all: a worker still inside native code then (an
octree insertion, a render) is let go and named, not waited for."""

from __future__ import annotations

import contextlib
import logging
import os
import sys
import threading
import time
from collections.abc import Callable
from types import TracebackType
from typing import Any

from abyss.common.errors import AbyssError

log = logging.getLogger(__name__)
JOIN_S = 3.0  # the part of a station's 5 s stop bound its threads may take
# Bulk work (onboard's perception, the simulation's sensor processes) runs below a station's
# periodic loops (physics and control every 50 ms) for the kernel's scheduler: on a loaded machine
# a loop woken at its tick preempts it, and where a CPU quota caps the station the quota goes to
# the loops first. Only where the GIL is not shared with a loop, or its holder gives it up within
# the switch interval (OpenCV's matcher releases it): a thread the kernel holds back while it holds
# the GIL holds the loop back with it.
BACKGROUND_NICE = 10
# a thread holding the GIL (Python between native calls) gives it up after this long: a loop woken
# at its tick waits at most this, not CPython's 5 ms
SWITCH_INTERVAL_S = 0.001


_children_cpu_s: dict[str, float] = {}  # a station's child processes: the CPU each last reported
_children_lock = threading.Lock()


def child_cpu(name: str, cpu_s: float) -> None:
    """A child process of this station (stations.simulation.offload) has used `cpu_s` so far."""
    with _children_lock:
        _children_cpu_s[name] = cpu_s


def children_cpu_s() -> float:
    """The CPU this station's child processes have used, for its own figure."""
    with _children_lock:
        return sum(_children_cpu_s.values())


def loops_first() -> None:
    """This process's threads take turns with the GIL often enough for a periodic loop."""
    sys.setswitchinterval(SWITCH_INTERVAL_S)


def in_background(thread: int = 0) -> None:
    """The calling thread (or thread id `thread`: a child process just started, before it starts
    threads of its own) below the station's periodic loops: the normal scheduler, even in a
    process at real-time priority (Realtime), at a nice value raising which needs no privilege."""
    thread = thread or threading.get_native_id()
    with contextlib.suppress(ProcessLookupError):  # a child that has already gone
        if os.sched_getscheduler(thread) != os.SCHED_OTHER:
            os.sched_setscheduler(thread, os.SCHED_OTHER, os.sched_param(0))
        os.setpriority(os.PRIO_PROCESS, thread, max(BACKGROUND_NICE, os.getpriority(os.PRIO_PROCESS, thread)))


# A loop late this many ticks in a row at real-time priority cannot keep its period whatever the
# priority: it gives the priority up rather than hold a core from every other process.
REALTIME_LATE_TICKS = 20


class Realtime:
    """Every thread of this process, and those it starts later (they inherit it), at SCHED_FIFO
    `priority` (1-99), as ros2_control runs its controller manager: a loop woken at its tick runs
    at once, whatever else the machine runs, and no thread of its own process holds the GIL while
    the kernel holds it back. Where the system does not allow it (no CAP_SYS_NICE or RLIMIT_RTPRIO,
    a cgroup with no real-time share), it stays on the normal scheduler and says why. The kernel
    keeps 5 % of each second for other processes (sched_rt_runtime_us); beyond that, a loop that
    runs late REALTIME_LATE_TICKS ticks in a row gives the priority up (`tick`)."""

    def __init__(self, priority: int, why_not: str = "") -> None:
        self.priority = 0
        self.why_not = why_not or "not asked for"
        self._late = 0
        if priority <= 0 or why_not:
            return
        try:
            _schedule_all(os.SCHED_FIFO, priority)
        except OSError as exc:
            _schedule_all(os.SCHED_OTHER, 0)
            self.why_not = f"not permitted here ({exc.strerror})"
            log.info("real-time priority %d %s: the normal scheduler", priority, self.why_not)
            return
        self.priority = priority

    def tick(self, late: bool) -> None:
        """The loop's last tick was `late`, or not."""
        if not self.priority:
            return
        self._late = self._late + 1 if late else 0
        if self._late >= REALTIME_LATE_TICKS:
            _schedule_all(os.SCHED_OTHER, 0)
            log.warning(
                "%d ticks late in a row at real-time priority %d: the loop cannot keep its "
                "period, back to the normal scheduler",
                self._late,
                self.priority,
            )
            self.priority, self.why_not = 0, f"given up after {self._late} ticks late in a row"

    @property
    def scheduler(self) -> str:
        """For the station's status: "fifo <priority>", or "normal (<why>)"."""
        return f"fifo {self.priority}" if self.priority else f"normal ({self.why_not})"


def _schedule_all(policy: int, priority: int) -> None:
    """Every thread of this process (threads below the loops stay as they are)."""
    for name in os.listdir("/proc/self/task"):
        thread = int(name)
        with contextlib.suppress(ProcessLookupError):  # it ended meanwhile
            if os.getpriority(os.PRIO_PROCESS, thread) < BACKGROUND_NICE:
                os.sched_setscheduler(thread, policy, os.sched_param(priority))


class WorkerFailed(AbyssError):
    """A worker thread of a station raised."""


class Workers:
    """`with Workers(bus.stop) as workers: workers.start("scene", loop, ...)`; the body is the
    station's main loop. Leaving the block sets `stop`, joins the workers and raises the first
    failure (a worker's, or the body's own, which wins)."""

    def __init__(self, stop: threading.Event, join_s: float = JOIN_S) -> None:
        self.stop = stop
        self.join_s = join_s
        self.failures: list[tuple[str, BaseException]] = []
        self.abandoned: list[str] = []  # workers still running when the group closed
        self._threads: list[threading.Thread] = []
        self._lock = threading.Lock()

    def start(self, name: str, target: Callable[..., None], *args: Any, background: bool = False) -> None:
        """Run `target(*args)` in a thread; `background`: below the periodic loops (in_background)."""
        thread = threading.Thread(
            target=self._run, args=(name, target, args, background), name=name, daemon=True
        )
        self._threads.append(thread)
        thread.start()

    def _run(self, name: str, target: Callable[..., None], args: tuple[Any, ...], background: bool) -> None:
        try:
            if background:
                in_background()
            target(*args)
        except BaseException as exc:  # every failure must reach the exit code
            log.exception("worker %s failed; stopping the station", name)
            with self._lock:
                self.failures.append((name, exc))
            self.stop.set()

    def __enter__(self) -> Workers:
        return self

    def __exit__(
        self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.stop.set()
        deadline = time.monotonic() + self.join_s
        for thread in self._threads:
            thread.join(timeout=max(0.0, deadline - time.monotonic()))
            if thread.is_alive():
                self.abandoned.append(thread.name)
        if self.abandoned:
            log.warning(
                "workers still running %.1f s after stop, let go: %s", self.join_s, ", ".join(self.abandoned)
            )
        with self._lock:
            failures = list(self.failures)
        if exc is None and failures:
            name, first = failures[0]
            raise WorkerFailed(f"worker {name} failed: {type(first).__name__}: {first}") from first
