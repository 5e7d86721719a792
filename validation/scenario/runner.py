"""`abyss scenario run`: each scenario as a whole isolated system (`abyss up` with its own
system id and ports, in its own process group), N at a time. The runner waits for the system
(and for the user's external stations), applies the timed events over Zenoh as an operator's
tools would, records onboard's state from its scoring key, and judges the assertions on what
the run left."""

from __future__ import annotations

import contextlib
import json
import logging
import math
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

import zenoh

from abyss.common import keys
from abyss.common.bus import open_session, zenoh_config
from abyss.common.clock import SimClock
from abyss.common.clock import follow as clock_follow
from abyss.common.errors import AbyssError, BadMessage
from abyss.common.lockstep import ENDLESS_S, PHASE_LEASE, TICK_TOLERANCE_S
from abyss.common.lockstep_testbed import Holds, Lease
from abyss.common.messages import LockstepReport, Telemetry, decode
from abyss.launch.state import RunState, wait_for_state
from abyss.validation.scenario.checks import Run, Verdict, judge, phase_began_s
from abyss.validation.scenario.events import Context, Event
from abyss.validation.scenario.spec import Scenario

log = logging.getLogger(__name__)
START_TIMEOUT_S = 60.0
HOLD_TIMEOUT_S = 120.0  # lockstep: for a hold to come, an event to take effect, a station to restart
# lockstep: and for each simulated second before a hold, this much more: an overloaded machine
# ran the mission at half real time, and a hold 70 s in timed out at 120 s
HOLD_WALL_PER_SIM_S = 10.0
SIM_CLOCK_HORIZON_S = 0.05  # the simulation's control period: its ticks' spacing
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


def carry_out(event: Event, ctx: Context) -> str:
    """One event carried out and, in lockstep (`ctx.holds`), waited on until it took effect;
    a line saying what was done."""
    done = event.apply(ctx)
    return done + (event.settled(ctx) if ctx.holds is not None else "")


class Held:
    """Events carried out in lockstep, each on its period: the simulation held there (common.lockstep's
    holds), the event applied and seen to take effect, then the hold released. An event timed on
    an intervention's phase is given its hold once onboard first reports the phase, in the
    telemetry of period T: T + at_s (two control periods at the least: the simulation must reach
    the next telemetry). Meanwhile the runner leases the simulation (`PHASE_LEASE`) only the
    periods before the earliest such a hold could still fall on, and leases on past a hold it
    added only once every station has it (common.lockstep)."""

    def __init__(self, scenario: Scenario, ctx: Context, timeline: Timeline) -> None:
        self.scenario, self.ctx, self.up, self.timeline = scenario, ctx, ctx.up, timeline
        config = scenario.configuration
        self.period_s = config.simulation.control_period_s
        # onboard tells its state every this many periods: its next report is this far on at the earliest
        self.telemetry_s = max(1, round(config.onboard.telemetry_period_s / self.period_s)) * self.period_s
        self.stations = ("simulation", *config.time.stations)  # each must have a hold added
        reject = lambda key, reason: log.warning("%s: %s", key, reason)  # noqa: E731
        self.lease = (
            Lease(ctx.session, ctx.system_id, reject, key=PHASE_LEASE) if scenario.phase_held else None
        )
        self.holds = self.lease if self.lease is not None else Holds(ctx.session, ctx.system_id, reject)
        ctx.holds = self.holds
        self.at: dict[float, list[Event]] = {}  # each hold's events
        for event in scenario.events:
            if not event.phase:
                self.at.setdefault(event.at_s, []).append(event)
        self.waiting = [e for e in scenario.events if e.phase]  # timed on a phase not yet reported
        self.since_s = 0.0  # the latest hold's period (a station restarted there reports from it)
        timeline.on_telemetry = self.holds.poke

    def at_s(self, event: Event) -> float:
        """How far into its phase an event timed on one lands in lockstep [s]."""
        return max(event.at_s, 2 * self.period_s)

    def _plan(self, say: Callable[[str], None]) -> None:
        """Holds for the phases onboard has reported, and the runner's lease."""
        for event in list(self.waiting):
            began_s = self.timeline.phase_stamp_s(event.phase)
            if began_s is None:
                continue
            self.waiting.remove(event)
            hold_s = began_s + self.at_s(event)  # on the first period at or after it
            if self.lease is not None and self.lease.until_s > hold_s - self.period_s + TICK_TOLERANCE_S:
                raise AbyssError(
                    f"{event.when()}: onboard's report of {event.phase} at t={began_s:.2f} s came after "
                    f"the simulation was leased to t={self.lease.until_s:.2f} s, past its hold; "
                    "run the scenario with --time real"
                )
            if hold_s not in self.at:
                self.holds.add_hold(hold_s)
            self.at.setdefault(hold_s, []).append(event)
            say(f"{event.when()}: {event.phase} reported at t={began_s:.2f} s, held at t={hold_s:.2f} s")
        if self.lease is None or not self.holds.have_holds(self.stations):
            return
        if not self.waiting:
            self.lease.grant(ENDLESS_S)
            return
        self.lease.grant(self._next_report_s() + min(map(self.at_s, self.waiting)) - self.period_s)

    def _next_report_s(self) -> float:
        """The earliest period onboard's next report of its state can be of. With one heard since
        the latest hold: that one's period and the reports' spacing. Before (its control starts
        only once the navigation and the joints come): one past the latest period it said it is
        done with (it sends its state before it says so), and no earlier than the hold (a station
        restarted there reports from there)."""
        latest_s = self.timeline.latest_stamp_s()
        if latest_s is not None and latest_s >= self.since_s - TICK_TOLERANCE_S:
            return latest_s + self.telemetry_s
        done = self.holds.reported("onboard", "done", self.holds.boot("onboard"))
        return max(self.since_s, done.sim_time_s + self.period_s) if done is not None else self.since_s

    def run(self, say: Callable[[str], None]) -> None:
        """Every hold in order: held, its events, released. A system that ended before a hold (a
        mission done before its time: the run stops when done) did not reach its events, as in
        real time; AbyssError if a hold is not reached or not left while it runs."""
        done: set[float] = set()
        while True:
            self._plan(say)
            target = min((h for h in self.at if h not in done), default=None)
            if target is None and not self.waiting:
                return
            later = self.scenario.duration_s if target is None else target
            timeout_s = HOLD_TIMEOUT_S + HOLD_WALL_PER_SIM_S * (later - self.since_s)

            def moved(target: float | None = target) -> bool:
                self._plan(say)
                if min((h for h in self.at if h not in done), default=None) != target:
                    return True  # a hold added before it: that one first
                return target is not None and self._held(target) is not None

            try:
                self.holds.wait(f"the simulation held at t={later:g} s", moved, self.up.running, timeout_s)
            except AbyssError:
                if self.up.running():
                    raise
                for hold_s in sorted(h for h in self.at if h not in done):
                    for event in self.at[hold_s]:
                        say(f"{event.when()}: not reached (the run ended first), {event.describe()} not done")
                for event in self.waiting:
                    say(f"{event.when()}: {event.phase} never reported, {event.describe()} not done")
                return
            held = self._held(target) if target is not None else None
            if held is None:
                continue  # a hold was added before the one waited for
            self.ctx.t_s, self.ctx.controls = held.sim_time_s, int(held.delivered.get("controls", 0.0))
            for event in self.at[target]:  # type: ignore[index]
                say(f"{event.when()} (period t={held.sim_time_s:.2f} s): {carry_out(event, self.ctx)}")
            self.since_s = held.sim_time_s
            # a station restarted here learns the holds added before it runs its first period
            self.holds.wait("every station's holds", self._everyone_has, self.up.running, HOLD_TIMEOUT_S)
            self._plan(say)  # its lease past the hold
            self.holds.release(held.sim_time_s, self.up.running, HOLD_TIMEOUT_S)
            done.add(target)  # type: ignore[arg-type]

    def _everyone_has(self) -> bool:
        return self.holds.have_holds(self.stations)

    def _held(self, hold_s: float) -> LockstepReport | None:
        """The simulation's report that it is held at `hold_s` (its latest boot), if it came."""
        report = self.holds.reported("simulation", "held", self.holds.boot("simulation"))
        return report if report is not None and report.sim_time_s >= hold_s - TICK_TOLERANCE_S else None

    def close(self) -> None:
        self.holds.close()


class Timeline:
    """Onboard's states as the scenario sees them, timed on the system's clock from the moment
    every station was up (in lockstep, each by its period: the simulated time it was sent at);
    Zenoh's callback appends to it."""

    def __init__(self, scenario: Scenario, run: Run) -> None:
        self.run = run
        self.lock = threading.Lock()
        self.up_s = 0.0  # when the system was up, on its clock
        timing = scenario.time  # events and onboard's states are timed on the system's clock
        self.lockstep = timing.mode == "lockstep"
        self.clock = SimClock(SIM_CLOCK_HORIZON_S, timing.speed_factor) if timing.simulated else None
        self._latest_s = -math.inf  # lockstep: the latest period onboard's state was heard of
        self._began_s: dict[str, float] = {}  # lockstep: the period of each phase's first report
        self.on_telemetry: Callable[[], None] = lambda: None

    def now_s(self) -> float:
        return self.clock.now_s() if self.clock is not None else time.monotonic()

    def since_up_s(self) -> float:
        return self.now_s() - self.up_s

    def on_state(self, sample: zenoh.Sample) -> None:
        try:
            received = decode(str(sample.key_expr), sample.payload.to_bytes(), Telemetry)
        except BadMessage:
            return
        state = received.message
        with self.lock:
            t_s = received.stamp_s if self.lockstep else self.since_up_s()
            self.run.states.append((t_s, state))
            self._latest_s = max(self._latest_s, received.stamp_s)
            if state.intervention_phase:
                self._began_s.setdefault(state.intervention_phase, received.stamp_s)
        self.on_telemetry()

    def phase_began_s(self, phase: str) -> float | None:
        with self.lock:
            return phase_began_s(self.run.states, phase)

    def phase_stamp_s(self, phase: str) -> float | None:
        """Lockstep: the period of onboard's first report of `phase`, if one came."""
        with self.lock:
            return self._began_s.get(phase)

    def latest_stamp_s(self) -> float | None:
        """Lockstep: the latest period onboard's state was heard of, if any was."""
        with self.lock:
            return self._latest_s if math.isfinite(self._latest_s) else None


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
