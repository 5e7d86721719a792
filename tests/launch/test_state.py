"""`state.json`: written whole or not at all, read back as written, and waited on without
waiting past the run's end."""

from __future__ import annotations

import dataclasses
import json
import threading
import time
from pathlib import Path
from typing import Any

import pytest

from abyss.launch.state import PHASES, STATE_FILE, RunState, StationState, wait_for_state


def a_state(**changes: Any) -> RunState:
    state = RunState("unit", "tcp/127.0.0.1:7447", 1234)
    state = state.with_station("simulation", pid=11, up=True)
    state = state.with_station("onboard", pid=12, restarts=2)
    state = state.with_station("vessel", external=True)
    return dataclasses.replace(state, **changes)


def test_write_then_read_gives_the_same_state(tmp_path: Path) -> None:
    written = a_state(
        phase="ended", mission_done=True, viewer="http://localhost:9090", verdict="ok", failure=""
    )
    written.write(tmp_path)
    read = RunState.read(tmp_path)
    assert read == written
    assert read is not None and read.stations["vessel"] == StationState(pid=None, external=True)
    assert isinstance(read.stations["onboard"], StationState) and read.stations["onboard"].restarts == 2
    table = json.loads((tmp_path / STATE_FILE).read_text())  # a plain file other programs read
    assert table["phase"] == "ended" and table["stations"]["simulation"] == {
        "pid": 11,
        "up": True,
        "restarts": 0,
        "external": False,
    }
    assert sorted(p.name for p in tmp_path.iterdir()) == [STATE_FILE]  # no partial file left


def test_with_station_changes_one_station_and_leaves_the_old_state_alone() -> None:
    before = a_state()
    after = before.with_station("onboard", up=True)
    assert after.stations["onboard"] == StationState(pid=12, up=True, restarts=2)
    assert before.stations["onboard"].up is False
    assert after.with_station("onshore").stations["onshore"] == StationState()


def test_read_before_any_write_or_of_a_broken_file_is_none(tmp_path: Path) -> None:
    assert RunState.read(tmp_path) is None
    assert RunState.read(tmp_path / "no such folder") is None
    (tmp_path / STATE_FILE).write_text('{"system": "unit", "endp')
    assert RunState.read(tmp_path) is None


@pytest.mark.parametrize("phase", ["", "running", "Up", "done"])
def test_a_phase_not_in_the_list_is_refused(phase: str) -> None:
    with pytest.raises(ValueError, match="phase"):
        RunState("unit", "tcp/127.0.0.1:7447", 1, phase=phase)
    with pytest.raises(ValueError, match="phase"):
        dataclasses.replace(a_state(), phase=phase)
    for good in PHASES:
        assert RunState("unit", "tcp/127.0.0.1:7447", 1, phase=good).phase == good


def test_a_write_that_fails_before_the_rename_leaves_the_previous_state_whole(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The file is never written in place: only the rename makes a new state visible."""
    a_state(phase="up").write(tmp_path)

    def crash(self: Path, target: Path) -> Path:
        raise OSError("disk gone")

    monkeypatch.setattr(Path, "replace", crash)
    with pytest.raises(OSError, match="disk gone"):
        a_state(phase="stopping", viewer="x" * 100_000).write(tmp_path)
    monkeypatch.undo()
    assert RunState.read(tmp_path) == a_state(phase="up")


def test_a_reader_never_sees_a_partial_file(tmp_path: Path) -> None:
    """A reader polling the file while it is rewritten again and again (states of a few hundred
    kB, more than one write to disk) sees every time a whole one."""
    states = [a_state(viewer=str(i) * 300_000) for i in range(10)]
    states[0].write(tmp_path)
    stop = threading.Event()
    reads: list[int] = []
    broken: list[str] = []

    def reader() -> None:
        path = tmp_path / STATE_FILE
        while not stop.is_set():
            try:
                text = path.read_text()
            except OSError as exc:  # gone for a moment: no better than a partial file
                broken.append(repr(exc))
                continue
            try:
                json.loads(text)
            except ValueError:
                broken.append(f"{len(text)} characters")
            reads.append(len(text))

    thread = threading.Thread(target=reader)
    thread.start()
    try:
        deadline = time.monotonic() + 3.0
        i = 0
        while (len(reads) < 200 or i < 200) and time.monotonic() < deadline:
            states[i % len(states)].write(tmp_path)
            i += 1
    finally:
        stop.set()
        thread.join()
    assert not broken, broken[:5]
    assert reads, "the reader never ran"


def test_wait_for_state_is_none_after_the_timeout(tmp_path: Path) -> None:
    a_state(phase="starting").write(tmp_path)
    t0 = time.monotonic()
    assert wait_for_state(tmp_path, lambda s: s.phase == "up", timeout_s=0.3) is None
    assert 0.3 <= time.monotonic() - t0 < 5.0
    assert wait_for_state(tmp_path / "never written", lambda s: True, timeout_s=0.1) is None


def test_wait_for_state_is_none_at_once_when_the_run_is_gone(tmp_path: Path) -> None:
    a_state(phase="starting").write(tmp_path)
    asked: list[bool] = []

    def running() -> bool:
        asked.append(True)
        return False

    t0 = time.monotonic()
    assert wait_for_state(tmp_path, lambda s: s.phase == "up", timeout_s=60.0, running=running) is None
    assert time.monotonic() - t0 < 5.0 and asked


def test_wait_for_state_is_none_at_once_when_the_run_ended_without_it(tmp_path: Path) -> None:
    a_state(phase="ended", verdict="failed").write(tmp_path)
    t0 = time.monotonic()
    assert wait_for_state(tmp_path, lambda s: s.mission_done, timeout_s=60.0) is None
    assert time.monotonic() - t0 < 5.0
    # but an ended state that holds is returned, and so is one that holds once the run is gone
    assert wait_for_state(tmp_path, lambda s: s.phase == "ended", 0.0) == a_state(
        phase="ended", verdict="failed"
    )
    assert wait_for_state(tmp_path, lambda s: s.verdict == "failed", 60.0, running=lambda: False)


def test_wait_for_state_returns_the_state_once_it_holds(tmp_path: Path) -> None:
    """The writer moves the run on only once the waiter has seen the state before: no sleeps."""
    seen_starting = threading.Event()
    seen: list[str] = []

    def holds(state: RunState) -> bool:
        seen.append(state.phase)
        if state.phase == "starting":
            seen_starting.set()
        return state.phase == "up" and state.stations["onboard"].up

    def writer() -> None:
        a_state(phase="starting").write(tmp_path)
        if seen_starting.wait(30.0):
            a_state(phase="up").write(tmp_path)  # up, but onboard not yet: does not hold
            a_state(phase="up").with_station("onboard", up=True).write(tmp_path)

    thread = threading.Thread(target=writer)
    thread.start()
    try:
        state = wait_for_state(tmp_path, holds, timeout_s=60.0)
    finally:
        thread.join()
    assert state == a_state(phase="up").with_station("onboard", up=True)
    assert seen[0] == "starting" and seen[-1] == "up"


def test_wait_for_state_polls_at_its_period(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """It reads the file again every POLL_PERIOD_S, not once per timeout."""
    reads: list[float] = []
    real_read = RunState.read

    def counting_read(run_dir: Path) -> RunState | None:
        reads.append(time.monotonic())
        return real_read(run_dir)

    monkeypatch.setattr(RunState, "read", staticmethod(counting_read))
    assert wait_for_state(tmp_path, lambda s: True, timeout_s=0.5) is None
    assert len(reads) >= 3  # 0.5 s at 0.05 s: about ten, fewer on a loaded machine
