"""A station's worker group (common.workers): a worker's failure stops the others and reaches
the exit as WorkerFailed, the body's own exception wins, a worker that ignores stop is let go
after join_s and named, workers that end normally leave nothing behind, a background worker runs
below the periodic loops, and real-time priority covers the loops' threads where it is allowed."""

from __future__ import annotations

import ctypes
import json
import os
import resource
import subprocess
import sys
import threading
import time

import pytest

from abyss.common.workers import BACKGROUND_NICE, REALTIME_LATE_TICKS, WorkerFailed, Workers

WAIT_S = 5.0  # a bound on waits that should end at once, never reached when the code works


def wait_for_stop(stop: threading.Event) -> None:
    stop.wait(WAIT_S)


def test_a_failing_worker_stops_the_group_and_is_named_in_worker_failed() -> None:
    stop = threading.Event()
    original = ValueError("bad octree")

    def fail() -> None:
        raise original

    with pytest.raises(WorkerFailed, match="scene") as raised, Workers(stop, join_s=2.0) as workers:
        workers.start("waiter", wait_for_stop, stop)
        workers.start("scene", fail)
        assert stop.wait(WAIT_S), "the failing worker did not set the stop event"
    assert raised.value.__cause__ is original
    assert "ValueError" in str(raised.value) and "bad octree" in str(raised.value)
    assert [name for name, _ in workers.failures] == ["scene"]
    assert workers.abandoned == []


def test_the_bodys_own_exception_wins_over_a_workers() -> None:
    stop = threading.Event()

    def fail() -> None:
        raise ValueError("worker")

    with pytest.raises(KeyError, match="body") as raised, Workers(stop, join_s=2.0) as workers:
        workers.start("scene", fail)
        assert stop.wait(WAIT_S)
        raise KeyError("body")
    assert not isinstance(raised.value, WorkerFailed)
    assert [name for name, _ in workers.failures] == ["scene"]  # seen, but not what propagates
    assert stop.is_set()


def test_a_worker_that_ignores_stop_is_let_go_after_join_s_and_named() -> None:
    stop, release = threading.Event(), threading.Event()
    join_s = 0.2
    try:
        workers = Workers(stop, join_s=join_s)
        with workers:
            workers.start("render", release.wait, WAIT_S)  # deaf to stop, as native code is
            workers.start("scene", wait_for_stop, stop)
            entered_exit_s = time.monotonic()
        left_s = time.monotonic() - entered_exit_s
        assert workers.abandoned == ["render"]
        assert workers.failures == []
        assert join_s * 0.9 <= left_s < 1.5, left_s  # waited for it about join_s, no longer
        assert stop.is_set()
    finally:
        release.set()


def test_workers_that_end_normally_leave_no_failure_and_none_abandoned() -> None:
    stop = threading.Event()
    done: list[str] = []
    with Workers(stop, join_s=2.0) as workers:
        workers.start("short", done.append, "short")
        workers.start("loop", lambda: (stop.wait(WAIT_S), done.append("loop")))
    assert sorted(done) == ["loop", "short"]  # both ran to their end before the group closed
    assert workers.abandoned == [] and workers.failures == []
    assert stop.is_set()


def test_a_background_worker_runs_below_the_loops_and_the_others_do_not() -> None:
    nice: dict[str, int] = {}

    def record(name: str) -> None:
        nice[name] = os.getpriority(os.PRIO_PROCESS, threading.get_native_id())

    own = os.getpriority(os.PRIO_PROCESS, threading.get_native_id())
    with Workers(threading.Event()) as workers:
        workers.start("render", record, "render", background=True)
        workers.start("control", record, "control")
    assert nice == {"render": max(BACKGROUND_NICE, own), "control": own}
    assert os.getpriority(os.PRIO_PROCESS, threading.get_native_id()) == own  # per thread, not the process


# A process that asks for real-time priority, then reports every thread's scheduler: its main
# thread, a thread started before the ask and one after (both inherit), a background worker,
# and what a loop late REALTIME_LATE_TICKS ticks in a row leaves.
REALTIME_PROBE = """
import json, os, threading
from abyss.common.workers import REALTIME_LATE_TICKS, Realtime, Workers, in_background

def policy(thread=0):
    return os.sched_getscheduler(thread or threading.get_native_id())

stop, seen = threading.Event(), {}
def watch(name, background=False):
    if background:
        in_background()
    seen[name] = threading.get_native_id()
    stop.wait()

with Workers(stop) as workers:
    workers.start("before", watch, "before")
    realtime = Realtime(10)
    workers.start("after", watch, "after")
    workers.start("bulk", watch, "bulk", True)
    while len(seen) < 3:
        stop.wait(0.01)
    report = {"asked": realtime.scheduler, "main": policy(),
              **{name: policy(thread) for name, thread in seen.items()}}
    for late in [True] * (REALTIME_LATE_TICKS - 1) + [False] + [True] * (REALTIME_LATE_TICKS - 1):
        realtime.tick(late)
    report["late but not for long"] = realtime.scheduler
    realtime.tick(True)
    report["late for long"] = realtime.scheduler
    report["after it"] = [policy(thread) for thread in [0, *seen.values()]]
    stop.set()
print(json.dumps(report))
"""


PR_CAPBSET_DROP, CAP_SYS_NICE = 24, 23  # linux/prctl.h, linux/capability.h


def without_sys_nice() -> None:
    """In the child before its exec: root without CAP_SYS_NICE (out of the bounding set, so out of
    what the exec'd program is permitted) and with no real-time priority allowed by its limits."""
    if os.geteuid() == 0 and ctypes.CDLL(None, use_errno=True).prctl(PR_CAPBSET_DROP, CAP_SYS_NICE, 0, 0, 0):
        raise OSError(ctypes.get_errno(), "prctl(PR_CAPBSET_DROP)")
    resource.setrlimit(resource.RLIMIT_RTPRIO, (0, 0))


def realtime_probe(allowed: bool) -> dict[str, object]:
    done = subprocess.run(
        [sys.executable, "-c", REALTIME_PROBE],
        capture_output=True,
        text=True,
        timeout=60,
        preexec_fn=None if allowed else without_sys_nice,
        check=True,
    )
    return dict(json.loads(done.stdout))


@pytest.mark.skipif(os.geteuid() != 0, reason="real-time priority needs root (CAP_SYS_NICE) here")
def test_realtime_puts_every_loop_thread_at_fifo_and_gives_it_up_when_late_for_long() -> None:
    report = realtime_probe(allowed=True)
    fifo, other = os.SCHED_FIFO, os.SCHED_OTHER
    assert report["asked"] == "fifo 10"
    assert (report["main"], report["before"], report["after"], report["bulk"]) == (fifo, fifo, fifo, other)
    assert report["late but not for long"] == "fifo 10"  # one tick on time starts the count afresh
    assert report["late for long"] == f"normal (given up after {REALTIME_LATE_TICKS} ticks late in a row)"
    assert report["after it"] == [other] * 4


def test_realtime_where_not_permitted_stays_normal_and_says_why() -> None:
    report = realtime_probe(allowed=False)
    assert report["asked"] == "normal (not permitted here (Operation not permitted))"
    assert {report[name] for name in ("main", "before", "after", "bulk")} == {os.SCHED_OTHER}
