"""A station's worker group (common.workers): a worker's failure stops the others and reaches
the exit as WorkerFailed, the body's own exception wins, a worker that ignores stop is let go
after join_s and named, workers that end normally leave nothing behind, and a background worker
runs below the periodic loops."""

from __future__ import annotations

import os
import threading
import time

import pytest

from abyss.common.workers import BACKGROUND_NICE, WorkerFailed, Workers

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
