"""`--time lockstep`: simulated time that repeats bit for bit (docs/architecture.md, Time).

Time moves in whole control periods, and only when the simulation says so (`SimTime` on
`abyss/<system>/clock`). Each station runs each period T in three phases (`Lockstep.period`):

1. its links deliver what is due by T, offered in an earlier period, and it says how many
   messages it delivered on each key so far (`LockstepReport`, phase "delivered");
2. it waits until it has received as many on each key a neighbour sends it (the Zenoh delivery
   order and timing no longer matter: everything due is in its inboxes, nothing more);
3. its loops due by T run one at a time, in the order of their names (`LockstepClock`: a loop's
   `Rate` waits for its turn), and it says it is done with T (phase "done").

The simulation, the master, steps to T + one period once every station is done with T.

Phase 1 of T + one period does not wait for its tick: a station done with T delivers the next
period's at once, as soon as each neighbour is done with T too (`Lockstep.deliver_ahead`: nothing
is offered to it before then, and no neighbour reads an inbox for T any more), and the simulation
says it is done with T once its physics has read its inputs, before it steps. So onboard's commands
for the next period cross while the physics steps, and the tick's round trip is off the period's
critical path; what is delivered, and when in simulated time, is what it was.

Holds (`time.holds_s`) are where the testbed acts: before a hold's period the simulation waits,
every station done with the period before, until the testbed releases it
(`lockstep_testbed.Holds`). In between, nothing moves: the testbed's fault lands on that period, a
link changes there, a station killed there loses exactly what it had not delivered, and its restart
(`ABYSS_BOOT` one more) runs its first period there. Counts are per epoch, from one hold to the
next: at a hold's period every station counts its deliveries and its arrivals anew (from what it
had verified by the period before), so a restarted station, whose counts start at zero, and its
neighbours agree again. Each station flushes its recording before a hold, so that one killed in it
leaves every message it sent.

A hold may also be added during the run (`time.phase_holds`: an event timed on an intervention's
phase, which no one knows in advance). The scenario runner then leases the simulation too
(`PHASE_LEASE`): it runs only the periods before the runner's lease, which the runner keeps short
of any period a hold could still be added at; the testbed tells every station the holds added
so far (phase `HOLDS`), each one takes them and reports how many it has, and the runner leases
past a hold only once every station has it. So an added hold is known to every station before
any reaches it, and lands on its period as a hold given at the start does.

Under `abyss up` (its pid in `SUPERVISOR_ENV`) the simulation is leased: it runs only the periods
before the testbed's lease (`lockstep_testbed.Lease`, a release that carries `LEASE`), and holds
before the first period past it, as at a hold but unseen by the other stations (no epoch begins, no
recording is flushed). The supervisor leases a second past shore's latest mission status, and ends
the lease a second past the first status that says done: the run stops there, every station done
with the period before, on the same period however late the supervisor heard the status
(launch.supervise, LockstepEnd).

So no thread interleaving, process scheduling or wall-clock moment decides anything: the same
seed and inputs give the same messages in the same periods, on any machine load. What is removed, and how:
thread interleaving (one loop at a time, in name order), Zenoh's delivery timing (counted phases),
wall-clock reads (every stamp, age and rate is the period's T), messages crossing a period
(a message offered in period T is delivered in a later one, however short its link), Zenoh's own
drops (every publisher blocks instead), and the wall-clock wait of a sender that finds an emulated
link's queue full (a reliable key's sender hands its turn back and goes on in the period the link
has room: `LockstepClock.step_aside`).
"""

from __future__ import annotations

import logging
import math
import os
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterable

import zenoh

from abyss.interface import keys
from abyss.interface.messages import LockstepReport, encode
from abyss.timing.clock import GUARD_WALL_S, Reject, SimClock, station_message

log = logging.getLogger(__name__)
TICK_TOLERANCE_S = 1e-6  # a loop due at T + this runs in period T (sums of periods in floats)
TESTBED = "testbed"  # the holds' releases come on abyss/<system>/testbed/lockstep
REPEAT_WALL_S = 0.5  # a report, or the clock, is told again this often while a station waits on it
WAIT_WARN_WALL_S = 10.0  # a wait this long is logged (a station gone, or not up yet)
# the supervisor's pid, set by `abyss up` for the stations it starts (launch.station, launch.start):
# a simulation started so runs the periods the supervisor leases it (`Lease`)
SUPERVISOR_ENV = "ABYSS_SUPERVISOR_PID"
LEASE = "lease"  # a testbed's release with this in `delivered` is a lease: the periods before it
# and with this, the scenario runner's lease while it waits for intervention phases (time.phase_holds)
PHASE_LEASE = "phase lease"
HOLDS = "holds"  # the testbed's holds added during the run (report phase), and each station's count
ENDLESS_S = 1e9  # a lease that never ends [simulated s] (a message's times are finite)


def hold_period(t_s: float, holds_s: Iterable[float], period_s: float) -> bool:
    """True if period `t_s` is a hold's: the first at or after one of `holds_s`."""
    return any(t_s - period_s + TICK_TOLERANCE_S < h_s <= t_s + TICK_TOLERANCE_S for h_s in holds_s)


def declare_reports(
    session: zenoh.Session,
    system: str,
    station: str,
    take: Callable[[str, LockstepReport], None],
    reject: Reject,
    listens: Iterable[str] = ("*",),
) -> tuple[zenoh.Publisher, list[zenoh.Subscriber]]:
    """`station`'s publisher of lockstep reports (blocking, express: a report is never dropped nor
    held back; to the other sessions only), and subscribers to the reports of `listens`
    (stations, or "*": every one's) that hand each report that decodes to `take(station,
    report)` (one that does not is rejected with its reason)."""

    def on_sample(sample: zenoh.Sample) -> None:
        got = station_message(sample, LockstepReport, reject)
        if got is not None:
            take(*got)

    publisher = session.declare_publisher(
        keys.lockstep_key(system, station),
        congestion_control=zenoh.CongestionControl.BLOCK,
        express=True,
        allowed_destination=zenoh.Locality.REMOTE,  # not back to its own subscribers: a callback saved
    )
    return publisher, [session.declare_subscriber(keys.lockstep_key(system, s), on_sample) for s in listens]


class LockstepClock(SimClock):
    """The period's time, exactly (no extrapolation), and the turns of the station's loops."""

    mode = "lockstep"

    def __init__(self) -> None:
        super().__init__(horizon_s=0.0)
        # one lock; the driver waits on _turns (a tick, a loop handing its turn back), each loop on
        # a condition of its own, so that a turn wakes the one thread it is for
        self._turn_lock = threading.RLock()
        self._turns = threading.Condition(self._turn_lock)
        self._turn_of: dict[str, threading.Condition] = {}
        self._due_s: dict[str, float] = {}  # each loop: the time it waits for
        self._turn: str | None = None  # the loop whose turn it is
        self.ticks: list[float] = []  # the periods the simulation announced, not yet run
        self.on_tick: Callable[[float], None] | None = None

    def tick(self, sim_time_s: float) -> None:
        """A period announced by the simulation: run by the station's driver (`Lockstep`), in order."""
        with self._turns:
            if sim_time_s > max(self.ticks, default=self._tick_s if self._tick_wall_s else -math.inf):
                self.ticks.append(sim_time_s)
                self._turns.notify_all()

    def set_period(self, t_s: float) -> None:
        with self._lock:
            self._tick_s, self._tick_wall_s, self._latest_s = t_s, time.monotonic(), t_s

    def now_s(self) -> float:
        with self._lock:
            return self._tick_s

    def wait(self, event: threading.Event, timeout_s: float) -> bool:
        raise RuntimeError("in lockstep a station waits for its turn: Rate with a name (Clock.sleep_until)")

    def done(self, loop: str, t_s: float) -> None:
        with self._turns:
            self._due_s.setdefault(loop, t_s)

    def enter(self, loop: str, t_s: float, stop: threading.Event) -> None:
        self.sleep_until(loop, t_s, stop)

    def _condition_of(self, loop: str) -> threading.Condition:
        """`loop`'s own condition (under the one lock: call with it held)."""
        condition = self._turn_of.get(loop)
        if condition is None:
            condition = self._turn_of[loop] = threading.Condition(self._turn_lock)
        return condition

    def step_aside(self, t_s: float, stop: threading.Event) -> bool:
        """A loop with nothing to do before `t_s` (blocked on a full emulated link until it has
        room, or its bulk work lasting until then) hands its turn back and goes on in its turn of
        the first period at or after `t_s` (the other loops and the periods in between run
        meanwhile); a thread that has no turn (a delivery, a callback) cannot wait: False (what a
        sender offered is dropped)."""
        loop = self.loop()
        with self._turns:
            if loop is None or self._turn != loop:
                return False
        # a later period's turn, never this one's again: room due within TICK_TOLERANCE_S of this
        # period (float sums) would bring it back here, where the link has no room yet
        return self.sleep_until(loop, max(t_s, self.now_s() + 2 * TICK_TOLERANCE_S), stop)

    def sleep_until(self, loop: str, t_s: float, stop: threading.Event) -> bool:
        """Wait for `loop`'s turn in the first period at or after `t_s`: False once `stop` is set."""
        self._runs(loop)
        with self._turns:
            self._due_s[loop] = t_s
            own = self._condition_of(loop)
            if self._turn == loop:
                self._turn = None
                self._turns.notify_all()  # the driver
            while not stop.is_set():
                if self._turn == loop:
                    return True
                own.wait(GUARD_WALL_S)
            return False

    def loops(self) -> set[str]:
        with self._turns:
            return set(self._due_s)

    def run_loops(self, t_s: float, stop: threading.Event) -> None:
        """Each loop due by `t_s`, one at a time in the order of their names, each until it waits
        again (a loop that starts in the period runs its first tick in it too)."""
        with self._turns:
            while not stop.is_set():
                due = sorted(loop for loop, at_s in self._due_s.items() if at_s <= t_s + TICK_TOLERANCE_S)
                if not due:
                    return
                loop = due[0]
                self._turn = loop
                self._condition_of(loop).notify_all()
                while self._turn == loop and not stop.is_set():
                    self._turns.wait(GUARD_WALL_S)
                self._turn = None

    def next_tick(self, stop: threading.Event) -> float | None:
        """The next period the simulation announced (None once `stop` is set)."""
        with self._turns:
            while not self.ticks:
                if stop.is_set():
                    return None
                self._turns.wait(GUARD_WALL_S)
            return self.ticks.pop(0)


class Lockstep:
    """One station's periods (see the module). `deliver_due(t_s)` is its links' delivery phase,
    returning what each key carried so far; `arrived()` what its bus received on each key;
    `expects()`: the neighbours whose deliveries it waits for, each with the keys it listens to;
    `loops`: the loops the station will have (it runs no period before all of them are there,
    whatever their start-up takes); `holds_s` and `period_s`: where the epochs begin (see the
    module); `end_s`: the run's end; `boot`: the station's; `before_hold`: what it does before a
    hold (its recording flushed); `listens`: the stations whose reports it hears (its
    neighbours; the simulation, which waits for every station, all of them); `leased`: it runs
    only the periods the testbed leases it (None: the simulation under `abyss up`, see the
    module)."""

    def __init__(
        self,
        session: zenoh.Session,
        system: str,
        station: str,
        clock: LockstepClock,
        deliver_due: Callable[[float], Counter[str]],
        arrived: Callable[[], Counter[str]],
        expects: Callable[[], dict[str, set[str]]],
        loops: Iterable[str],
        stop: threading.Event,
        reject: Reject,
        holds_s: tuple[float, ...] = (),
        period_s: float = 0.0,
        end_s: float = 0.0,
        boot: int = 0,
        before_hold: Callable[[], None] = lambda: None,
        listens: Iterable[str] = ("*",),
        leased: bool | None = None,
        phase_leased: bool = False,
    ) -> None:
        self.system, self.station, self.clock, self.stop = system, station, clock, stop
        self.leased = (station == "simulation" and SUPERVISOR_ENV in os.environ) if leased is None else leased
        self._lease_s = 0.0  # leased: it runs the periods before this
        self.phase_leased = phase_leased  # and before the scenario runner's lease (see the module)
        self._phase_lease_s = 0.0
        self._added_s: tuple[float, ...] = ()  # the holds the testbed added during the run
        self.holds_s, self.period_s, self.end_s = holds_s, period_s, end_s
        self.boot, self.before_hold = boot, before_hold
        self._ahead_s = -math.inf  # the period whose deliveries were made ahead (deliver_ahead)
        self._delivered_base: Counter[str] = Counter()  # this station's deliveries before the epoch
        self._arrived_base: Counter[str] = Counter()  # and its neighbours', that it verified
        self._last_delivered: Counter[str] = Counter()  # its deliveries so far
        self._verified: dict[str, float] = {}  # per key: the neighbour's count it waited for, in the epoch
        self._ran = False  # a period
        self.deliver_due, self.arrived, self.expects = deliver_due, arrived, expects
        self._neighbours = sorted(expects())  # the hop's stations: fixed, whatever keys it listens to
        self.loops = set(loops)
        self._cond = threading.Condition()
        self._reports: dict[tuple[str, str], tuple[float, dict[str, float]]] = {}  # (station, phase)
        self._seq = 0
        self._publisher, self._subscribers = declare_reports(
            session, system, station, self._take, reject, listens
        )
        self._last: dict[str, tuple[float, dict[str, float]]] = {}  # per phase: the latest report
        self._tell_now = threading.Event()  # the repeats told at once (a count of holds changed)
        self._repeater = threading.Thread(target=self._repeat, name="lockstep reports", daemon=True)
        self._repeater.start()

    def notify(self) -> None:
        """Something this station waits for may have come (a message arrived)."""
        with self._cond:
            self._cond.notify_all()

    # -- reports -------------------------------------------------------------------------
    def _take(self, station: str, report: LockstepReport) -> None:
        with self._cond:
            if station == TESTBED and report.phase == "release" and LEASE in report.delivered:
                self._lease_s = max(self._lease_s, report.sim_time_s)
                self._cond.notify_all()
                return
            if station == TESTBED and report.phase == "release" and PHASE_LEASE in report.delivered:
                self._phase_lease_s = max(self._phase_lease_s, report.sim_time_s)
                self._cond.notify_all()
                return
            if station == TESTBED and report.phase == HOLDS:
                self._add_holds(tuple(report.delivered.values()))
                return
            before = self._reports.get((station, report.phase))
            if before is None or report.sim_time_s >= before[0]:
                self._reports[(station, report.phase)] = (report.sim_time_s, dict(report.delivered))
                self._cond.notify_all()

    def report(self, t_s: float, phase: str, delivered: dict[str, float] | None = None) -> None:
        with self._cond:
            self._last[phase] = (t_s, delivered or {})
            self._send(phase)

    def _send(self, phase: str) -> None:
        t_s, delivered = self._last[phase]
        self._publisher.put(
            encode(
                LockstepReport(sim_time_s=t_s, phase=phase, delivered=delivered, boot=self.boot),
                self._seq,
                time.time(),
            )
        )
        self._seq += 1

    def _repeat(self) -> None:
        """Tell the latest report of each phase again every REPEAT_WALL_S (one that a station
        subscribed too late for, still starting, is heard then), and at once when told to (a
        report set where a blocking publisher may not be used: Zenoh's callback)."""
        while not self.stop.is_set():
            self._tell_now.wait(REPEAT_WALL_S)
            self._tell_now.clear()
            with self._cond:
                for phase in list(self._last) if not self.stop.is_set() else ():
                    self._send(phase)

    def reported(self, station: str, phase: str) -> tuple[float, dict[str, float]]:
        with self._cond:
            return self._reports.get((station, phase), (-math.inf, {}))

    def wait_for(
        self, what: str, ready: Callable[[], bool], waiting: Callable[[], None] = lambda: None
    ) -> bool:
        """Block until `ready()` (checked on every report and every GUARD_WALL_S), calling `waiting`
        every REPEAT_WALL_S; False once `stop` is set. A long wait is logged once."""
        started_s = time.monotonic()
        repeat_s, warned = started_s + REPEAT_WALL_S, False
        with self._cond:
            while not ready():
                if self.stop.is_set():
                    return False
                now_s = time.monotonic()
                if now_s >= repeat_s:
                    waiting()
                    repeat_s = now_s + REPEAT_WALL_S
                if not warned and now_s - started_s > WAIT_WARN_WALL_S:
                    warned = True
                    log.warning("%s: waiting %.0f s for %s", self.station, WAIT_WARN_WALL_S, what)
                self._cond.wait(GUARD_WALL_S)
        return True

    # -- holds and epochs -----------------------------------------------------------------
    def hold_period(self, t_s: float) -> bool:
        """True if period `t_s` is a hold's: the first at or after one of `holds_s` (an epoch's first)."""
        return hold_period(t_s, self.holds_s, self.period_s)

    def _add_holds(self, added_s: tuple[float, ...]) -> None:
        """The testbed's holds added during the run (all of them, each time: a station that
        started later hears them too), before this station reaches any (see the module): taken
        into its holds, and their count reported, which the testbed waits for before it leases on.
        The count is told by the repeats' one thread (a blocking publisher is not for Zenoh's
        callback), always the latest: a thread per addition could tell an older count last."""
        with self._cond:
            if len(added_s) <= len(self._added_s):
                return  # a repeat: the count is told again with the station's other reports
            self._added_s = added_s
            self.holds_s = tuple(sorted(set(self.holds_s) | set(added_s)))
            self._last[HOLDS] = (float(len(added_s)), {})
        self._tell_now.set()

    def leased_to(self, t_s: float) -> bool:
        """True if this station may run period `t_s`: not leased, or the leases go past it."""
        return (not self.leased or t_s < self._lease_s - TICK_TOLERANCE_S) and (
            not self.phase_leased or t_s < self._phase_lease_s - TICK_TOLERANCE_S
        )

    def hold_at(self, t_s: float) -> bool:
        """True if the simulation holds before period `t_s`: a hold's, or one its lease does not
        reach (yet)."""
        with self._cond:
            return self.hold_period(t_s) or not self.leased_to(t_s)

    def _new_epoch(self) -> None:
        """Count anew from here: what this station delivered so far, and what it verified of its
        neighbours' deliveries by the period before (not what arrived: a neighbour already in
        this period may have delivered more), become the bases."""
        self._delivered_base = Counter(self._last_delivered)
        for key, count in self._verified.items():
            self._arrived_base[key] += int(count)
        self._verified = {}

    def hold(self, t_s: float, apply: Callable[[], int]) -> bool:
        """The simulation, before a hold's period `t_s` or one past its lease (every station done
        with the one before): at a hold its recording flushed, it says it is held and waits for
        the testbed's release and its lease, applying what the testbed sends meanwhile (`apply`:
        the faults taken, counted in its report); False once `stop` is set."""
        hold = self.hold_period(t_s)
        if hold:
            self.before_hold()
        applied = 0
        self.report(t_s, "held", {"controls": 0.0})

        def released() -> bool:
            nonlocal applied
            if taken := apply():
                applied += taken
                self.report(t_s, "held", {"controls": float(applied)})
            release_s = self.reported(TESTBED, "release")[0]
            return (not hold or release_s >= t_s - TICK_TOLERANCE_S) and self.leased_to(t_s)

        what = "release" if hold else "lease"
        return self.wait_for(f"the testbed's {what} at t={t_s:.2f} s", released)

    # -- a period ------------------------------------------------------------------------
    def _deliver(self, t_s: float) -> None:
        """Phase 1 of period `t_s`: the links deliver what is due by then, and say how much."""
        self._last_delivered = self.deliver_due(t_s)
        self.report(
            t_s,
            "delivered",
            {key: float(n - self._delivered_base[key]) for key, n in self._last_delivered.items()},
        )

    def deliver_ahead(self, t_s: float) -> bool:
        """Done with period `t_s`, deliver the next one's now rather than on its tick, once every
        neighbour is done with `t_s` too (none then reads an inbox for `t_s` any more, and this
        station offers nothing more before the next period): the tick's round trip leaves the
        critical path, and a neighbour's inputs are there when its period begins. Not into a
        hold's period (the testbed acts there first) nor past the run's end; False once `stop`
        is set."""
        next_s = t_s + self.period_s
        if self.hold_period(next_s) or (self.end_s and next_s >= self.end_s - TICK_TOLERANCE_S):
            return not self.stop.is_set()
        if not self.wait_for(
            f"{', '.join(self._neighbours)} done at t={t_s:.2f} s",
            lambda: all(
                self._reports.get((n, "done"), (-math.inf,))[0] >= t_s - TICK_TOLERANCE_S
                for n in self._neighbours
            ),
        ):
            return False
        self._deliver(next_s)
        self._ahead_s = next_s
        return True

    def period(self, t_s: float, waiting: Callable[[], None] = lambda: None) -> bool:
        """Phases 1-3 of period `t_s` (without the report that it is done: the simulation's
        physics comes after its loops); False once `stop` is set."""
        if not self.wait_for(
            f"its loops {sorted(self.loops - self.clock.loops())}",
            lambda: self.loops <= self.clock.loops(),
            waiting,
        ):
            return False
        if self.hold_period(t_s):
            self._new_epoch()
        self._ran = True
        self.clock.set_period(t_s)
        if abs(self._ahead_s - t_s) > TICK_TOLERANCE_S:  # not delivered ahead (deliver_ahead)
            self._deliver(t_s)

        expects = self.expects()
        verified: dict[str, float] = {}

        def all_arrived() -> bool:
            arrived = self.arrived()
            verified.clear()
            for neighbour, keys_ in expects.items():
                at_s, counts = self._reports.get((neighbour, "delivered"), (-math.inf, {}))
                if at_s < t_s - TICK_TOLERANCE_S:
                    return False
                for key in keys_:
                    if arrived[key] - self._arrived_base[key] < (count := counts.get(key, 0.0)):
                        return False
                    verified[key] = count
            return True

        if not self.wait_for(
            f"the deliveries of {', '.join(sorted(expects))} at t={t_s:.2f} s", all_arrived, waiting
        ):
            return False
        self._verified = verified
        self.clock.run_loops(t_s, self.stop)
        return not self.stop.is_set()

    def run(self) -> None:
        """A station's driver: ready once its loops are there, then each period the simulation
        announces, in order, then done, and the next period's deliveries made ahead; none from
        `end_s` on (the run's end: the simulation tells it, and holds still). A restarted
        station runs its first period at a hold (the testbed lets it in there); its recording
        is flushed before each hold."""
        if not self.wait_for("its loops", lambda: self.loops <= self.clock.loops()):
            return
        self.report(0.0, "ready")
        while (t_s := self.clock.next_tick(self.stop)) is not None:
            if self.end_s and t_s >= self.end_s - TICK_TOLERANCE_S:
                continue
            if self.boot and not self._ran and not self.hold_period(t_s):
                continue  # restarted between holds: it waits for the next (see the module)
            if not self.period(t_s):
                return
            if self.hold_period(t_s + self.period_s):
                self.before_hold()
            self.report(t_s, "done")
            if not self.deliver_ahead(t_s):
                return

    def close(self) -> None:
        """Undeclared once stopped (`stop` set): the publisher not while the repeats publish (the
        subscribers outside the lock, which a callback in flight may be waiting for)."""
        for subscriber in self._subscribers:
            subscriber.undeclare()
        with self._cond:
            self._publisher.undeclare()
