"""`--time lockstep`: simulated time that repeats bit for bit (docs/architecture.md, Time).

Time moves in whole control periods, and only when the simulation says so (`SimTime` on
`abyss/<system>/clock`). Each station runs each period T in three phases (`Lockstep.period`):

1. its links deliver what is due by T, offered in an earlier period, and it says how many
   messages it delivered on each key so far (`LockstepReport`, phase "delivered");
2. it waits until it has received as many on each key a neighbour sends it (the Zenoh delivery
   order and timing no longer matter: everything due is in its inboxes, nothing more);
3. its loops due by T run one at a time, in the order of their names (`LockstepClock`: a loop's
   `Rate` waits for its turn), and it says it is done with T (phase "done").

The simulation, the master, steps to T + one period once every station is done with T. So no
thread interleaving, process scheduling or wall-clock moment decides anything: the same seed and
inputs give the same messages in the same periods, on any machine load. What is removed, and how:
thread interleaving (one loop at a time, in name order), Zenoh's delivery timing (counted phases),
wall-clock reads (every stamp, age and rate is the period's T), messages crossing a period
(a message offered in period T is delivered in a later one, however short its link), Zenoh's own
drops (every publisher blocks instead), and an emulated link's full queue (a sender never waits for
room: what does not fit is dropped and counted).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterable

import zenoh

from abyss.common import keys
from abyss.common.clock import POLL_WALL_S, Reject, SimClock, station_message
from abyss.common.messages import LockstepReport, encode

log = logging.getLogger(__name__)
TICK_TOLERANCE_S = 1e-6  # a loop due at T + this runs in period T (sums of periods in floats)
REPEAT_WALL_S = 0.5  # a report, or the clock, is told again this often while a station waits on it
WAIT_WARN_WALL_S = 10.0  # a wait this long is logged (a station gone, or not up yet)


class LockstepClock(SimClock):
    """The period's time, exactly (no extrapolation), and the turns of the station's loops."""

    mode = "lockstep"

    def __init__(self) -> None:
        super().__init__(horizon_s=0.0)
        self._turns = threading.Condition()
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

    def sleep_until(self, loop: str, t_s: float, stop: threading.Event) -> bool:
        """Wait for `loop`'s turn in the first period at or after `t_s`: False once `stop` is set."""
        with self._turns:
            self._due_s[loop] = t_s
            if self._turn == loop:
                self._turn = None
                self._turns.notify_all()
            while not stop.is_set():
                if self._turn == loop:
                    return True
                self._turns.wait(POLL_WALL_S)
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
                self._turns.notify_all()
                while self._turn == loop and not stop.is_set():
                    self._turns.wait(POLL_WALL_S)
                self._turn = None

    def next_tick(self, stop: threading.Event) -> float | None:
        """The next period the simulation announced (None once `stop` is set)."""
        with self._turns:
            while not self.ticks:
                if stop.is_set():
                    return None
                self._turns.wait(POLL_WALL_S)
            return self.ticks.pop(0)


class Lockstep:
    """One station's periods (see the module). `deliver_due(t_s)` is its links' delivery phase,
    returning what each key carried so far; `arrived()` what its bus received on each key;
    `expects()`: the neighbours whose deliveries it waits for, each with the keys it listens to;
    `loops`: the loops the station will have (it runs no period before all of them are there,
    whatever their start-up takes)."""

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
    ) -> None:
        self.system, self.station, self.clock, self.stop = system, station, clock, stop
        self.deliver_due, self.arrived, self.expects = deliver_due, arrived, expects
        self.loops = set(loops)
        self._cond = threading.Condition()
        self._reports: dict[tuple[str, str], tuple[float, dict[str, float]]] = {}  # (station, phase)
        self._seq = 0
        self.reject = reject
        self._publisher = session.declare_publisher(
            keys.lockstep_key(system, station), congestion_control=zenoh.CongestionControl.BLOCK, express=True
        )
        self._subscriber = session.declare_subscriber(keys.lockstep_key(system, "*"), self._on_report)
        self._last: dict[str, tuple[float, dict[str, float]]] = {}  # per phase: the latest report
        self._repeater = threading.Thread(target=self._repeat, name="lockstep reports", daemon=True)
        self._repeater.start()

    def notify(self) -> None:
        """Something this station waits for may have come (a message arrived)."""
        with self._cond:
            self._cond.notify_all()

    # -- reports -------------------------------------------------------------------------
    def _on_report(self, sample: zenoh.Sample) -> None:
        got = station_message(sample, LockstepReport, self.reject)
        if got is None:
            return
        station, report = got
        with self._cond:
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
            encode(LockstepReport(sim_time_s=t_s, phase=phase, delivered=delivered), self._seq, time.time())
        )
        self._seq += 1

    def _repeat(self) -> None:
        """Tell the latest report of each phase again every REPEAT_WALL_S: one that a station
        subscribed too late for (still starting) is heard then."""
        while not self.stop.wait(REPEAT_WALL_S):
            with self._cond:
                for phase in list(self._last):
                    self._send(phase)

    def reported(self, station: str, phase: str) -> tuple[float, dict[str, float]]:
        with self._cond:
            return self._reports.get((station, phase), (-math.inf, {}))

    def wait_for(
        self, what: str, ready: Callable[[], bool], waiting: Callable[[], None] = lambda: None
    ) -> bool:
        """Block until `ready()` (checked on every report and every POLL_WALL_S), calling `waiting`
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
                self._cond.wait(POLL_WALL_S)
        return True

    # -- a period ------------------------------------------------------------------------
    def period(self, t_s: float, waiting: Callable[[], None] = lambda: None) -> bool:
        """Phases 1-3 of period `t_s` (without the report that it is done: the simulation's
        physics comes after its loops); False once `stop` is set."""
        if not self.wait_for(
            f"its loops {sorted(self.loops - self.clock.loops())}",
            lambda: self.loops <= self.clock.loops(),
            waiting,
        ):
            return False
        self.clock.set_period(t_s)
        delivered = self.deliver_due(t_s)
        self.report(t_s, "delivered", {key: float(n) for key, n in delivered.items()})

        expects = self.expects()

        def all_arrived() -> bool:
            arrived = self.arrived()
            for neighbour, keys_ in expects.items():
                at_s, counts = self._reports.get((neighbour, "delivered"), (-math.inf, {}))
                if at_s < t_s - TICK_TOLERANCE_S:
                    return False
                if any(arrived[key] < counts.get(key, 0.0) for key in keys_):
                    return False
            return True

        if not self.wait_for(
            f"the deliveries of {', '.join(sorted(expects))} at t={t_s:.2f} s", all_arrived, waiting
        ):
            return False
        self.clock.run_loops(t_s, self.stop)
        return not self.stop.is_set()

    def run(self, end_s: float = 0.0) -> None:
        """A station's driver: each period the simulation announces, in order, then done; none
        from `end_s` on (the run's end: the simulation tells it, and holds still)."""
        while (t_s := self.clock.next_tick(self.stop)) is not None:
            if end_s and t_s >= end_s - TICK_TOLERANCE_S:
                continue
            if not self.period(t_s):
                return
            self.report(t_s, "done")

    def close(self) -> None:
        self._subscriber.undeclare()
        self._publisher.undeclare()
