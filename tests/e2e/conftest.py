from __future__ import annotations

import contextlib
import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, ClassVar

import pytest
import zenoh
from hosts import Hosts, usable

from abyss.bus.session import open_session, zenoh_config
from abyss.interface import keys
from abyss.interface.messages import NavState, decode
from abyss.launch.state import RunState, wait_for_state

ROOT = Path(__file__).resolve().parents[2]
# the mission before the interventions (done in about 30 s, not 60): waypoints, then the fingers
# either side of the middle valve's handle; for the tests that need a mission to end, not to work
ARM_MISSION = (
    "--set",
    "mission.interventions=[]",
    "--set",
    "mission.arm_target=[4.86, 0, -8.35, 1.5708, 0, 0]",
)
# the recorded run's (`recorded_run`), which a hybrid run flies again with a vehicle replaying it
RECORDED_MISSION = (
    *("--keep-running", "--duration", "40"),
    *("--set", "simulation.camera_rate_hz=0.5", "--set", "vessel.scene_track_period_s=1"),
    *ARM_MISSION,
)


@pytest.fixture
def hosts() -> Iterator[Hosts]:
    """A lab of network namespaces of its own (root, /dev/net/tun), removed after the test."""
    if reason := usable():
        pytest.skip(reason)
    made = Hosts()
    try:
        yield made.make()
    finally:
        made.remove()


class Process:
    """A process as a user runs it, its output (stdout and stderr) read line by line as it comes."""

    def __init__(self, command: list[str], cwd: Path, env: dict[str, str] | None = None) -> None:
        self.process = subprocess.Popen(
            command,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            cwd=cwd,
            env=dict(os.environ, PYTHONUNBUFFERED="1", **(env or {})),
            start_new_session=True,
        )  # its children share its process group: a failed test kills them all
        self.lines: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.process.stdout is not None
        for line in self.process.stdout:
            self.lines.append(line.rstrip("\n"))

    def wait_for(self, pattern: str, timeout_s: float = 60.0) -> re.Match[str]:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            for line in list(self.lines):
                if m := re.search(pattern, line):
                    return m
            if self.process.poll() is not None and not self._reader.is_alive():
                break
            time.sleep(0.05)
        raise AssertionError(f"no line matching {pattern!r}; output:\n" + "\n".join(self.lines))

    def wait(self, timeout_s: float = 60.0) -> int:
        code = self.process.wait(timeout=timeout_s)
        self._reader.join(timeout=5)
        if self.process.stdout is not None:
            self.process.stdout.close()
        return code

    def output(self) -> str:
        return "\n".join(self.lines)


class Up(Process):
    """`abyss up` as a user runs it."""

    started: ClassVar[list[Up]] = []

    def __init__(self, out: Path, *args: str) -> None:
        Up.started.append(self)
        self.out = out
        super().__init__(
            [sys.executable, "-P", "-m", "abyss.cli", "up", "--port", "0", "--out", str(out), *args],
            out.parent,
        )

    def state(self, holds: Callable[[RunState], bool] = lambda _: True, timeout_s: float = 60.0) -> RunState:
        """`abyss up`'s state.json, once `holds` is true of it."""
        state = wait_for_state(self.out, holds, timeout_s, lambda: self.process.poll() is None)
        if state is None:
            raise AssertionError(
                f"state.json never held; state {RunState.read(self.out)}; output:\n" + "\n".join(self.lines)
            )
        return state

    def wait_up(self, timeout_s: float = 60.0) -> RunState:
        """Once every station is up."""
        return self.state(lambda s: s.phase == "up", timeout_s)

    @property
    def endpoint(self) -> str:
        return self.state().endpoint

    def stop(self, timeout_s: float = 60.0) -> int:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
        return self.wait(timeout_s)

    def interrupt(self, timeout_s: float = 60.0) -> str:
        """Ctrl-C, as a user ends a run kept running: its verdict, which must agree with the exit
        code (done: 0, interrupted: 130) and name no failure."""
        code = self.stop(timeout_s)
        verdict = str(self.summary()["verdict"])
        assert (verdict, code) in (("done", 0), ("interrupted", 130)), (verdict, code, self.output())
        return verdict

    def summary(self) -> dict[str, Any]:
        return json.loads((self.out / "summary.json").read_text())


@pytest.fixture(autouse=True)
def no_leftover_systems() -> Iterator[None]:
    """A failed test still stops what it started, so nothing leaks into the next test."""
    yield
    while Up.started:
        up = Up.started.pop()
        with contextlib.suppress(ProcessLookupError):
            os.killpg(up.process.pid, signal.SIGKILL)  # the supervisor and any station it left
        up.wait(30)


@pytest.fixture(scope="session")
def recorded_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One mission (ARM_MISSION), recorded (`--record all`, the rerun recording saved), shared by the
    tests that read, export and replay a recording: its run directory. It runs on for 10 s past
    the mission's end (done at about 30 s) so that the scene stream has reached shore whole, with
    the cameras at half their rate: the live vessel drops clouds it cannot insert in time (a
    bounded inbox), as many as the machine is busy, and a replay (no rendering, no fusion) is less
    busy than the recorded run; at one cloud a second the vessel keeps up in both. The vessel
    gathers the octree's changes each second rather than every 5 s: shore's final map is compared
    with a replay's, and a run stops wherever the gathering is (up to a period of changes apart)."""
    out = tmp_path_factory.mktemp("recorded") / "run"
    done = subprocess.run(
        [
            sys.executable,
            "-P",
            "-m",
            "abyss.cli",
            "up",
            "--port",
            "0",
            "--out",
            str(out),
            "--viewer",
            "save",
            "--record",
            "all",
            *RECORDED_MISSION,
        ],
        capture_output=True,
        text=True,
        cwd=out.parent,
        timeout=240,
    )
    summary = json.loads((out / "summary.json").read_text())
    assert done.returncode == 0 and summary["verdict"] == "done", done.stdout + done.stderr
    return out


def abyss(*args: str, timeout_s: float = 60.0, cwd: Path = ROOT) -> subprocess.CompletedProcess[str]:
    """An abyss command as a user types it, in `cwd` (-P: that directory never shadows abyss)."""
    return subprocess.run(
        [sys.executable, "-P", "-m", "abyss.cli", *args],
        capture_output=True,
        text=True,
        cwd=cwd,
        timeout=timeout_s,
    )


class Truth:
    """The vehicle's true state, as a scorer sees it on the truth key."""

    def __init__(self, endpoint: str, system: str) -> None:
        self.states: list[NavState] = []
        self._lock = threading.Lock()
        self.session = open_session(zenoh_config(connect=[endpoint], mode="client"), "test scorer")
        self.subscriber = self.session.declare_subscriber(keys.truth_key(system), self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        message = decode(str(sample.key_expr), sample.payload.to_bytes()).message
        assert isinstance(message, NavState)
        with self._lock:
            self.states.append(message)

    def since(self, seconds: float) -> list[NavState]:
        with self._lock:
            latest = self.states[-1].sim_time_s
            return [s for s in self.states if s.sim_time_s >= latest - seconds]

    def close(self) -> None:
        self.subscriber.undeclare()
        self.session.close()
