"""Timed events in a scenario run: in lockstep each carried out on its period (`Held`: the
simulation held there, the event applied and seen to take effect, released), and onboard's states
as the run sees them (`Timeline`), which events timed on an intervention's phase are placed by."""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable

import zenoh

from abyss.common.errors import AbyssError, BadMessage
from abyss.interface.messages import LockstepReport, Telemetry, decode
from abyss.timing.clock import SimClock
from abyss.timing.lockstep import ENDLESS_S, PHASE_LEASE, TICK_TOLERANCE_S
from abyss.timing.lockstep_testbed import Holds, Lease
from abyss.validation.scenario.checks import Run, phase_began_s
from abyss.validation.scenario.events import Context, Event
from abyss.validation.scenario.spec import Scenario

log = logging.getLogger(__name__)
HOLD_TIMEOUT_S = 120.0  # lockstep: for a hold to come, an event to take effect, a station to restart
# lockstep: and for each simulated second before a hold, this much more: an overloaded machine
# ran the mission at half real time, and a hold 70 s in timed out at 120 s
HOLD_WALL_PER_SIM_S = 10.0
SIM_CLOCK_HORIZON_S = 0.05  # the simulation's control period: its ticks' spacing


def carry_out(event: Event, ctx: Context) -> str:
    """One event carried out and, in lockstep (`ctx.holds`), waited on until it took effect;
    a line saying what was done."""
    done = event.apply(ctx)
    return done + (event.settled(ctx) if ctx.holds is not None else "")


class Held:
    """Events carried out in lockstep, each on its period: the simulation held there (timing.lockstep's
    holds), the event applied and seen to take effect, then the hold released. An event timed on
    an intervention's phase is given its hold once onboard first reports the phase, in the
    telemetry of period T: T + at_s (two control periods at the least: the simulation must reach
    the next telemetry). Meanwhile the runner leases the simulation (`PHASE_LEASE`) only the
    periods before the earliest such a hold could still fall on, and leases on past a hold it
    added only once every station has it (timing.lockstep)."""

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
            except AbyssError as e:
                if self.up.running():
                    raise AbyssError(f"{e} ({self._where()})") from None
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

    def _where(self) -> str:
        """Where the holds stand: what a run that stood still says of them."""
        held = self.holds.reported("simulation", "held", self.holds.boot("simulation"))
        lacking = [s for s in self.stations if not self.holds.have_holds((s,))]
        return "; ".join(
            (
                f"the simulation last held at t={held.sim_time_s:.2f} s" if held else "never held",
                f"leased to t={self.lease.until_s:.2f} s" if self.lease is not None else "not leased",
                f"without every added hold: {', '.join(lacking)}"
                if lacking
                else "every station has the holds",
            )
        )

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
