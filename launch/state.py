"""`state.json`: what a running `abyss up` is doing, for the programs that drive it (the scenario
runner, the pytest fixture, the tests, a team's CI script) instead of reading its output.

`abyss up` rewrites the file atomically (write, then rename) on every change: its endpoint,
each station's pid, whether it is up and how often it was restarted, the run's phase
(`starting`, `up`, `stopping`, `ended`), whether shore saw the mission done, and at the end
the verdict. A reader never sees half a file."""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, Literal, get_args

from abyss.common.runfiles import write_whole

STATE_FILE = "state.json"
Phase = Literal["starting", "up", "stopping", "ended"]  # the run's phase, in this order
PHASES: tuple[Phase, ...] = get_args(Phase)
# how a run ended (launch.verdict.VERDICTS: what `abyss up` exits with); "" until it ended
Verdict = Literal["done", "incomplete", "interrupted", "failed"]
POLL_PERIOD_S = 0.05


@dataclass(frozen=True)
class StationState:
    pid: int | None = None  # None for an external station (the user's own)
    up: bool = False  # its liveliness token is seen now
    restarts: int = 0
    external: bool = False


@dataclass(frozen=True)
class RunState:
    system: str
    endpoint: str
    supervisor_pid: int
    phase: Phase = "starting"
    stations: dict[str, StationState] = field(default_factory=dict)
    mission_done: bool = False
    viewer: str = ""  # where to look: the web viewer's address or the recording
    verdict: Verdict | Literal[""] = ""  # once ended
    failure: str = ""

    def __post_init__(self) -> None:
        if self.phase not in PHASES:
            raise ValueError(f"phase {self.phase!r} not one of {', '.join(PHASES)}")

    def with_station(self, name: str, **changes: Any) -> RunState:
        stations = dict(self.stations)
        stations[name] = replace(stations.get(name, StationState()), **changes)
        return replace(self, stations=stations)

    def write(self, run_dir: Path) -> None:
        write_whole(run_dir / STATE_FILE, json.dumps(asdict(self), indent=2))

    @staticmethod
    def read(run_dir: Path) -> RunState | None:
        """The run's state, or None before `abyss up` wrote it."""
        try:
            table = json.loads((run_dir / STATE_FILE).read_text())
        except (OSError, ValueError):
            return None
        stations = {name: StationState(**s) for name, s in table.pop("stations").items()}
        return RunState(stations=stations, **table)


def wait_for_state(
    run_dir: Path,
    holds: Callable[[RunState], bool],
    timeout_s: float,
    running: Callable[[], bool] = lambda: True,
) -> RunState | None:
    """The first state of the run for which `holds` is true, or None when `timeout_s` passes or
    the run ends (`running` false, the phase `ended`) before it does."""
    deadline = time.monotonic() + timeout_s
    while True:
        state = RunState.read(run_dir)
        if state is not None and holds(state):
            return state
        if time.monotonic() >= deadline or not running() or (state is not None and state.phase == "ended"):
            return None
        time.sleep(POLL_PERIOD_S)
