"""The testbed's side of lockstep (timing.lockstep tells the whole protocol): `Holds`, what each
station reported last in each phase and the release of a hold, which the scenario runner carries
its events out in; and `Lease`, the periods the supervisor leases a simulation started by
`abyss up`, so that a run stopped when its mission is done ends on the same period every time."""

from __future__ import annotations

import math
import threading
import time
from collections import Counter
from collections.abc import Callable

import zenoh

from abyss.common.errors import AbyssError
from abyss.interface.messages import LockstepReport, encode
from abyss.timing.clock import POLL_WALL_S, Reject
from abyss.timing.lockstep import HOLDS, LEASE, REPEAT_WALL_S, TESTBED, TICK_TOLERANCE_S, declare_reports


class Holds:
    """The testbed's side of the holds (see the module): what each station reported last in each
    phase, with its boot, and the release of a hold."""

    def __init__(self, session: zenoh.Session, system: str, reject: Reject) -> None:
        self._cond = threading.Condition()
        self._latest: dict[tuple[str, str], LockstepReport] = {}
        self._boot: Counter[str] = Counter()  # each station's latest boot heard
        self._publisher, self._subscribers = declare_reports(session, system, TESTBED, self._take, reject)
        self._seq = 0
        self._added_s: tuple[float, ...] = ()  # the holds this testbed added during the run
        self._closed = threading.Event()
        self._put_lock = threading.Lock()
        threading.Thread(target=self._repeat, name="testbed reports", daemon=True).start()

    def _take(self, station: str, report: LockstepReport) -> None:
        """A station's report, kept if it is its latest: of a later boot, or of the same boot and
        no earlier (a phase's times, and a count of holds, only grow within a boot; one published
        before another may still arrive after it)."""
        with self._cond:
            before = self._latest.get((station, report.phase))
            if report.boot < self._boot[station] or (
                before is not None and before.boot == report.boot and report.sim_time_s < before.sim_time_s
            ):
                return
            self._boot[station] = report.boot
            self._latest[(station, report.phase)] = report
            self._cond.notify_all()

    def poke(self) -> None:
        """Wake a `wait` to look again (something it looks at changed outside the reports)."""
        with self._cond:
            self._cond.notify_all()

    def boot(self, station: str) -> int:
        with self._cond:
            return self._boot[station]

    def reported(self, station: str, phase: str, min_boot: int = 0) -> LockstepReport | None:
        """`station`'s latest report in `phase`, if one of boot `min_boot` or later came."""
        with self._cond:
            report = self._latest.get((station, phase))
            return report if report is not None and report.boot >= min_boot else None

    def wait(self, what: str, ready: Callable[[], bool], alive: Callable[[], bool], timeout_s: float) -> None:
        """Until `ready()`; AbyssError naming `what` if the system ends (`alive` false) or
        `timeout_s` passes first."""
        deadline_s = time.monotonic() + timeout_s
        while not ready():  # without the lock: `ready` may query the system (a link's profile)
            if not alive():
                raise AbyssError(f"the system ended while waiting for {what}")
            if time.monotonic() > deadline_s:
                raise AbyssError(f"waited {timeout_s:g} s for {what}")
            with self._cond:
                self._cond.wait(POLL_WALL_S * 5)

    def held(
        self, hold_s: float, min_boot: int, alive: Callable[[], bool], timeout_s: float
    ) -> LockstepReport:
        """The simulation's report that it is held at the hold `hold_s` (boot `min_boot` or later)."""

        def held() -> LockstepReport | None:
            report = self.reported("simulation", "held", min_boot)
            return report if report is not None and report.sim_time_s >= hold_s - TICK_TOLERANCE_S else None

        self.wait(f"the simulation held at t={hold_s:g} s", lambda: held() is not None, alive, timeout_s)
        report = held()
        assert report is not None
        return report

    def add_hold(self, hold_s: float) -> None:
        """A hold added during the run (timing.lockstep): every station is told, now and every
        REPEAT_WALL_S (a station restarted later hears it too); `have_holds` says when each has it."""
        with self._cond:
            self._added_s = (*self._added_s, hold_s)
        self._tell_holds()

    def _tell_holds(self) -> None:
        with self._cond:
            if not self._added_s:
                return
            message = LockstepReport(
                sim_time_s=max(self._added_s),
                phase=HOLDS,
                delivered={str(i): h_s for i, h_s in enumerate(self._added_s)},
                boot=0,
            )
            self._put(message)

    def have_holds(self, stations: tuple[str, ...]) -> bool:
        """True once each of `stations` (its latest boot) has every hold this testbed added."""
        with self._cond:
            count = len(self._added_s)
        return not count or all(
            (r := self.reported(s, HOLDS, self.boot(s))) is not None and r.sim_time_s >= count
            for s in stations
        )

    def added_holds_s(self) -> tuple[float, ...]:
        """The holds a testbed (the scenario runner) added during the run, as this one heard them."""
        report = self.reported(TESTBED, HOLDS)
        return tuple(report.delivered.values()) if report is not None else ()

    def _repeat(self) -> None:
        while not self._closed.wait(REPEAT_WALL_S):
            self._tell_holds()

    def release(self, t_s: float, alive: Callable[[], bool], timeout_s: float) -> None:
        """Let the simulation go on from its hold at `t_s`: told until it has delivered that period."""
        told_s = -math.inf

        def gone_on() -> bool:
            nonlocal told_s
            delivered = self.reported("simulation", "delivered", self._boot["simulation"])
            if delivered is not None and delivered.sim_time_s >= t_s - TICK_TOLERANCE_S:
                return True
            if time.monotonic() - told_s >= REPEAT_WALL_S:
                told_s = time.monotonic()
                message = LockstepReport(sim_time_s=t_s, phase="release", boot=0)
                self._put(message)
            return False

        self.wait(f"the simulation to go on from t={t_s:g} s", gone_on, alive, timeout_s)

    def _put(self, message: LockstepReport) -> None:
        """Publish (from any thread: a wait, the repeats), nothing once closed."""
        with self._put_lock:
            if not self._closed.is_set():
                self._publisher.put(encode(message, self._seq, time.time()))
                self._seq += 1

    def close(self) -> None:
        with self._put_lock:  # not while a repeat publishes
            self._closed.set()
            for subscriber in self._subscribers:
                subscriber.undeclare()
            self._publisher.undeclare()


class Lease(Holds):
    """The testbed's lease of periods to a leased simulation (see the module): it runs the
    periods before `until_s`, which only grows; told at once when it grows and again by `tell`
    every REPEAT_WALL_S (a simulation that starts or restarts later hears it then). And, as
    `Holds`, what each station reported last. `key`: the supervisor's lease (LEASE) or the
    scenario runner's (PHASE_LEASE)."""

    def __init__(
        self, session: zenoh.Session, system: str, reject: Reject, until_s: float = 0.0, key: str = LEASE
    ) -> None:
        self._lease_lock = threading.Lock()
        self.until_s, self.key = until_s, key
        self._told_wall_s = -math.inf
        super().__init__(session, system, reject)

    def grant(self, until_s: float) -> None:
        """Lease the periods before `until_s` [simulated s] (a shorter lease changes nothing)."""
        with self._lease_lock:
            if until_s > self.until_s:
                self.until_s = until_s
                self._tell()

    def tell(self) -> None:
        """Tell the lease again if it was not told for REPEAT_WALL_S."""
        with self._lease_lock:
            if time.monotonic() - self._told_wall_s >= REPEAT_WALL_S:
                self._tell()

    def _repeat(self) -> None:
        while not self._closed.wait(REPEAT_WALL_S):
            self._tell_holds()
            self.tell()

    def _tell(self) -> None:
        self._told_wall_s = time.monotonic()
        message = LockstepReport(sim_time_s=self.until_s, phase="release", delivered={self.key: 1.0}, boot=0)
        self._put(message)

    def held_at(self, t_s: float) -> bool:
        """True once the simulation (its latest boot) is held at `t_s` or later."""
        report = self.reported("simulation", "held", self.boot("simulation"))
        return report is not None and report.sim_time_s >= t_s - TICK_TOLERANCE_S

    def delivered_at(self, station: str, t_s: float) -> bool:
        """True once `station` (its latest boot) delivered period `t_s` or a later one."""
        report = self.reported(station, "delivered", self.boot(station))
        return report is not None and report.sim_time_s >= t_s - TICK_TOLERANCE_S
