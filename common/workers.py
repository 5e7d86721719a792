"""A station's threads as one group, the way trio's nurseries hold tasks: each worker runs until
the station's stop event is set; the first worker to raise sets it for all, and its exception
reaches the station's exit code when the group closes instead of dying silently in a thread.
Closing never waits longer than `join_s` in all: a worker still inside native code then (an
octree insertion, a render) is let go and named, not waited for."""

from __future__ import annotations

import logging
import os
import sys
import threading
import time
from collections.abc import Callable
from types import TracebackType
from typing import Any

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


def in_background() -> None:
    """The calling thread below the station's periodic loops (a thread's nice value: raising it
    needs no privilege)."""
    thread = threading.get_native_id()
    os.setpriority(os.PRIO_PROCESS, thread, max(BACKGROUND_NICE, os.getpriority(os.PRIO_PROCESS, thread)))


class WorkerFailed(RuntimeError):
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
        thread = threading.Thread(target=self._run, args=(name, target, args, background), name=name,
                                  daemon=True)
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

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.stop.set()
        deadline = time.monotonic() + self.join_s
        for thread in self._threads:
            thread.join(timeout=max(0.0, deadline - time.monotonic()))
            if thread.is_alive():
                self.abandoned.append(thread.name)
        if self.abandoned:
            log.warning("workers still running %.1f s after stop, let go: %s", self.join_s,
                        ", ".join(self.abandoned))
        with self._lock:
            failures = list(self.failures)
        if exc is None and failures:
            name, first = failures[0]
            raise WorkerFailed(f"worker {name} failed: {type(first).__name__}: {first}") from first
