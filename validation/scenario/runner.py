"""`abyss scenario run`: each scenario as a whole isolated system (`abyss up` with its own
system id and ports, in its own process group), N at a time. The runner waits for the system
(and for the user's external stations), applies the timed events over Zenoh as an operator's
tools would, records onboard's state from its scoring key, and judges the assertions on what
the run left."""

from __future__ import annotations

import contextlib
import json
import logging
import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

from abyss.bus.session import open_session, zenoh_config
from abyss.common.errors import AbyssError
from abyss.interface import keys
from abyss.launch.state import RunState, wait_for_state
from abyss.timing.clock import follow as clock_follow
from abyss.validation.scenario.checks import Run, Verdict, judge
from abyss.validation.scenario.events import Context
from abyss.validation.scenario.held import HOLD_TIMEOUT_S, Held, Timeline, carry_out
from abyss.validation.scenario.spec import Scenario

log = logging.getLogger(__name__)
START_TIMEOUT_S = 60.0
EXTERNAL_TIMEOUT_S = 180.0
SHOWN = ("waiting for external station", "died with exit code", "restarted")  # abyss up's lines passed on
CONFIG_FILE = "scenario-config.json"  # the run's configuration, as `abyss up --config` reads it


@dataclass
class Result:
    scenario: Scenario
    out_dir: Path
    verdicts: list[Verdict]
    passed: bool
    wall_s: float
    error: str = ""  # why the run itself did not complete
    run_verdict: str = ""  # abyss up's: done, incomplete, interrupted or failed

    @property
    def outcome(self) -> str:
        """The scenario's word: `failed` when an assertion did not come out as the scenario
        expects or the run did not complete, else abyss up's verdict."""
        return self.run_verdict if self.passed and self.run_verdict else "failed"

    @property
    def wrong(self) -> list[Verdict]:
        """The assertions that did not come out as the scenario expects: failed, or held where
        it names them in `expect_failed`."""
        return [v for v in self.verdicts if v.passed == (v.assertion.kind in self.scenario.expect_failed)]

    @property
    def why_failed(self) -> str:
        """One line: the run's error, or each wrong assertion with its figure; '' when passed."""
        if self.passed:
            return ""
        if self.error:
            return self.error.splitlines()[0]
        return "; ".join(map(str, self.wrong))


class System:
    """One `abyss up` for a scenario, its output read line by line."""

    def __init__(self, scenario: Scenario, system_id: str, out_dir: Path, say: Callable[[str], None]) -> None:
        self.say = say
        self.out_dir = out_dir
        config_path = out_dir / CONFIG_FILE
        config_path.write_text(json.dumps(scenario.up_table(), indent=2) + "\n")
        command = [
            sys.executable,
            "-P",  # the current directory never shadows abyss's modules
            "-m",
            "abyss.cli",
            "up",
            "--config",
            str(config_path),
            "--port",
            "0",
            "--out",
            str(out_dir),
            "--system",
            system_id,
            "--duration",
            f"{scenario.duration_s:g}",
            "--viewer",
            "save",
            "--console",
            "none",  # unattended: no pilot's page, nothing more on the run's own session
        ]
        command += [] if scenario.stop_when_done else ["--keep-running"]
        command += ["--restart"] if scenario.restart else []
        for name in scenario.external:
            command += ["--external", name]
        self.process = subprocess.Popen(
            command,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            cwd=out_dir,
            start_new_session=True,
            env=dict(os.environ, PYTHONUNBUFFERED="1"),
        )
        self.lines: list[str] = []
        self.reader = threading.Thread(target=self._read, daemon=True)
        self.reader.start()

    def _read(self) -> None:
        assert self.process.stdout is not None
        for line in self.process.stdout:
            self.lines.append(line.rstrip("\n"))
            if line.startswith("abyss:") and any(what in line for what in SHOWN):
                self.say(line.strip().removeprefix("abyss: ").strip())

    def running(self) -> bool:
        return self.process.poll() is None

    def state(
        self, holds: Callable[[RunState], bool] = lambda _: True, timeout_s: float = 0.0
    ) -> RunState | None:
        """`abyss up`'s state (`state.json`) once `holds` is true of it; None if it is not in time."""
        return wait_for_state(self.out_dir, holds, timeout_s, self.running)

    def wait_for(self, pattern: str, timeout_s: float) -> re.Match[str] | None:
        """The first line of `abyss up`'s output that matches `pattern` (for what a person reads:
        the command to start an external station); None if none does in time."""
        deadline = time.monotonic() + timeout_s
        while True:
            for line in list(self.lines):
                if m := re.search(pattern, line):
                    return m
            if time.monotonic() >= deadline or not self.running():
                return None
            time.sleep(0.05)

    def kill(self) -> None:
        """SIGKILL the run, after asking each station for its threads' stacks (SIGUSR1: into its
        log), so that a run that stood still says where."""
        state = self.out_dir / "state.json"
        stations = json.loads(state.read_text()).get("stations", {}) if state.exists() else {}
        for pid in (s.get("pid") for s in stations.values()):
            with contextlib.suppress(ProcessLookupError, TypeError):
                os.kill(pid, signal.SIGUSR1)
        time.sleep(0.5 if stations else 0.0)
        with contextlib.suppress(ProcessLookupError):
            os.killpg(self.process.pid, signal.SIGKILL)


def run_scenario(
    scenario: Scenario,
    out_dir: Path,
    index: int,
    say: Callable[[str], None],
    started: Callable[[System, str], None] | None = None,
) -> Result:
    """Run one scenario to its end; `started(system, system_id)` is called once `abyss up` runs."""
    t0 = time.monotonic()
    system_id = f"{scenario.name}-{os.getpid()}-{index}"[-64:]
    out_dir = out_dir.resolve()  # abyss up runs in a directory of its own
    out_dir.mkdir(parents=True, exist_ok=True)
    up = System(scenario, system_id, out_dir, say)
    if started is not None:
        started(up, system_id)
    run = Run({}, robot=scenario.configuration.simulation.robot)
    error = ""
    try:
        timeout_s = START_TIMEOUT_S + (EXTERNAL_TIMEOUT_S if scenario.external else 0.0)
        state = up.state(lambda s: s.phase == "up", timeout_s)
        if state is None:
            error = "the system did not come up:\n" + "\n".join(up.lines[-20:])
            up.kill()
        else:
            say(f"up in {time.monotonic() - t0:.1f} s")
            error = _drive(scenario, up, state.endpoint, system_id, Timeline(scenario, run), say)
    finally:
        up.process.wait()
        up.reader.join(timeout=5)
        if up.process.stdout is not None:
            up.process.stdout.close()
    error = _collect(out_dir, up, run, error)
    verdicts = judge(run, scenario.assertions) if not error else []
    failed = {v.assertion.kind for v in verdicts if not v.passed}
    passed = not error and failed == set(scenario.expect_failed)
    _plot(out_dir, say)
    return Result(
        scenario, out_dir, verdicts, passed, time.monotonic() - t0, error, str(run.summary.get("verdict", ""))
    )


def _drive(
    scenario: Scenario,
    up: System,
    endpoint: str,
    system_id: str,
    timeline: Timeline,
    say: Callable[[str], None],
) -> str:
    """Apply the scenario's events at their times while onboard's states are recorded, then wait
    for `abyss up` to end: '' or why it did not in time."""
    session = open_session(zenoh_config(connect=[endpoint], mode="client"), "abyss scenario")
    ticks = clock_follow(session, system_id, timeline.clock) if timeline.clock is not None else None
    timeline.up_s = timeline.now_s()
    subscriber = session.declare_subscriber(keys.onboard_state_key(system_id), timeline.on_state)
    ctx = Context(session, system_id, up, scenario.restart, HOLD_TIMEOUT_S)
    held = Held(scenario, ctx, timeline) if scenario.held else None
    try:
        if held is not None:
            held.run(say)
        wall_deadline_s = time.monotonic() + scenario.duration_s + 90.0  # simulated time may stand still
        for event in scenario.events if held is None else ():
            while up.process.poll() is None:
                if time.monotonic() > wall_deadline_s:
                    raise subprocess.TimeoutExpired("abyss up", scenario.duration_s + 90.0)
                origin_s = timeline.phase_began_s(event.phase)
                if origin_s is not None and timeline.since_up_s() >= origin_s + event.at_s:
                    break
                time.sleep(0.05)
            if up.process.poll() is not None:
                say(f"{event.when()}: not reached, {event.describe()} not done")
                break
            at_s = timeline.since_up_s()
            say(f"{event.when()} (t={at_s:.1f} s): {carry_out(event, ctx)}")
        up.process.wait(timeout=scenario.duration_s + 90.0)
    except subprocess.TimeoutExpired:
        up.kill()
        return "abyss up did not stop in time"
    except AbyssError as exc:  # a hold not reached or not left (the system stopped, or a station hung)
        up.kill()
        return f"lockstep: {exc}"
    finally:
        timeline.run.killed = ctx.killed
        if held is not None:
            held.close()
        subscriber.undeclare()
        if ticks is not None:
            ticks.undeclare()
        session.close()
    return ""


def _collect(out_dir: Path, up: System, run: Run, error: str) -> str:
    """What the run left (its summary, the commands shore sent, `abyss up`'s output) into `run`;
    the error, or why there is no summary."""
    summary_path = out_dir / "summary.json"
    if summary_path.exists():
        run.summary = json.loads(summary_path.read_text())
    elif not error:
        error = "no summary.json:\n" + "\n".join(up.lines[-20:])
    commands_path = out_dir / "commands.json"
    run.commands = json.loads(commands_path.read_text()) if commands_path.exists() else []
    (out_dir / "output.log").write_text("\n".join(up.lines) + "\n")
    return error


def _plot(out_dir: Path, say: Callable[[str], None]) -> None:
    if (out_dir / "control.csv").exists():
        from abyss.validation.plot import plot_run

        try:
            plot_run(out_dir)
        except (AbyssError, OSError) as exc:  # too short a run to plot
            say(f"no plots: {exc}")


def run_all(scenarios: Sequence[Scenario], out_dir: Path, parallel: int) -> list[Result]:
    """Every scenario, `parallel` at a time, with a line of progress per step."""
    lock = threading.Lock()
    total = len(scenarios)

    def one(item: tuple[int, Scenario]) -> Result:
        index, scenario = item

        def say(text: str) -> None:
            with lock:
                print(f"[{index + 1}/{total} {scenario.name}] {text}", flush=True)

        say(f"starting ({scenario.use}): {scenario.description}".rstrip(": "))
        result = run_scenario(scenario, out_dir / "runs" / f"{index:02d}-{scenario.name}", index, say)
        held = sum(v.passed for v in result.verdicts)
        say(
            f"{'PASS' if result.passed else 'FAIL'} ({result.outcome}) in {result.wall_s:.0f} s: {held}/"
            f"{len(result.verdicts)} assertions held"
            + (f" (expected to fail: {', '.join(scenario.expect_failed)})" if scenario.expect_failed else "")
            + (f"; {result.error}" if result.error else "")
        )
        for v in result.verdicts:
            say(f"    {'ok  ' if v.passed else 'FAIL'} {v.assertion.describe()}: {v.detail}")
        return result

    with ThreadPoolExecutor(max_workers=parallel) as pool:
        return list(pool.map(one, enumerate(scenarios)))
