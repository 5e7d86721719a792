"""abyss's pytest plugin (registered as `abyss` on install): the `abyss_system` fixture brings
up a whole system for a team's own tests, as a scenario describes it (profiles, external
stations, timed faults, assertions), and tears it down after the test; the test talks to it
while it runs and gets the summary and the verdicts when it ends.

    def test_my_driver(abyss_system):
        system = abyss_system("scenarios/external-onboard.toml")   # or a dict shaped like the file
        system.wait_for("waiting for external station onboard")
        start_my_driver(system.endpoint, system.system_id)
        result = system.result(timeout_s=120)
        assert result.passed, result.verdicts

    system = abyss_system("scenarios/nominal.toml", time="sim", speed="4")  # faster than real time
"""

from __future__ import annotations

import re
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest


class RunningSystem:
    """A scenario's whole system, run in a background thread."""

    def __init__(self, scenario: Any, out_dir: Path) -> None:
        from abyss.validation.scenario.runner import Result, System, run_scenario

        self.scenario = scenario
        self.lines: list[str] = []
        self._up: System | None = None
        self.system_id = ""
        self._started = threading.Event()
        self._result: Result | None = None

        def started(up: System, system_id: str) -> None:
            self._up, self.system_id = up, system_id
            self._started.set()

        def run() -> None:
            self._result = run_scenario(scenario, out_dir, 0, self.lines.append, started)
            self._started.set()

        self._thread = threading.Thread(target=run, name=f"abyss {scenario.name}", daemon=True)
        self._thread.start()
        self._started.wait(30.0)

    def wait_for(self, pattern: str, timeout_s: float = 60.0) -> re.Match[str]:
        """The first line of `abyss up`'s output that matches."""
        assert self._up is not None, "abyss up did not start"
        found = self._up.wait_for(pattern, timeout_s)
        if found is None:
            raise AssertionError(f"no line matching {pattern!r}:\n" + "\n".join(self._up.lines[-30:]))
        return found

    def wait_up(self, timeout_s: float = 60.0) -> Any:
        """`abyss up`'s state (`abyss.launch.state.RunState`) once every station is up."""
        assert self._up is not None, "abyss up did not start"
        state = self._up.state(lambda s: s.phase == "up", timeout_s)
        if state is None:
            raise AssertionError("the system did not come up:\n" + "\n".join(self._up.lines[-30:]))
        return state

    @property
    def endpoint(self) -> str:
        """The Zenoh endpoint to connect your own component to (from `abyss up`'s state.json)."""
        assert self._up is not None, "abyss up did not start"
        state = self._up.state(timeout_s=60.0)
        if state is None:
            raise AssertionError("abyss up wrote no state.json:\n" + "\n".join(self._up.lines[-30:]))
        return state.endpoint

    def result(self, timeout_s: float = 300.0) -> Any:
        """The run's Result (summary verdicts, run directory) once it has ended."""
        self._thread.join(timeout_s)
        if self._result is None:
            raise AssertionError(f"scenario {self.scenario.name} did not end in {timeout_s:g} s")
        return self._result

    def stop(self) -> None:
        if self._up is not None:
            self._up.kill()
        self._thread.join(30.0)


@pytest.fixture
def abyss_system(tmp_path: Path) -> Iterator[Any]:
    """A factory: `abyss_system(path_or_table)` starts a whole system; all are stopped after."""
    from abyss.validation.scenario.spec import load_scenario, scenario_of

    running: list[RunningSystem] = []

    def start(
        scenario: str | Path | dict[str, Any], time: str | None = None, speed: str | None = None
    ) -> RunningSystem:
        """`time`: real, sim or lockstep (default: the scenario's own), `speed` with sim; a scenario
        that cannot follow simulated time (an external station, a CPU cap) fails to start then."""
        spec = scenario_of(scenario) if isinstance(scenario, dict) else load_scenario(Path(scenario))
        if time is not None or speed is not None:
            spec, why = spec.on_time(time or "sim", speed)
            if why:
                raise pytest.UsageError(f"{spec.name} {why}: it cannot run with time={time}")
        system = RunningSystem(spec, tmp_path / f"abyss-{spec.name}-{len(running)}")
        running.append(system)
        return system

    yield start
    for system in running:
        system.stop()
