"""One time source per system (docs/architecture.md, Time).

`real`: every station keeps time by its own monotonic clock and stamps with the wall clock, as
stations on separate hosts do. `sim`: the simulation is the clock. It publishes its time after
each control period on `abyss/<system>/clock` (a `SimTime`, outside the links), every other
station's `SimClock` follows it, and every rate, timeout, heartbeat, failsafe timer and emulated
link delay runs on it. A station's periodic loops say how far in simulated time they are done
(`SimClock.done`: a loop waiting for its next tick needs nothing before it); the shell
publishes the slowest on `abyss/<system>/<station>/progress`, and
the simulation steps past t only once every station is done with t minus `time.max_lag_s`
(`Holdback`): a station that needs more CPU than the speed leaves it slows the whole system
down instead of falling behind it, so a run at speed 4 sees what one at speed 1 sees.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Iterable
from typing import TypeVar

import zenoh

from abyss.common.errors import BadMessage
from abyss.interface import keys
from abyss.interface.messages import Message, SimTime, decode, encode

log = logging.getLogger(__name__)
POLL_WALL_S = 0.02  # a wait on simulated time looks at the clock at least this often [wall s]
GUARD_WALL_S = 0.1  # a wait woken by ticks looks at its stop event at least this often [wall s]
# a laggard whose progress stood this long while the simulation held for it fails the run, naming it:
# simulated time that stands still is a bug to see, never a pause to let go of (docs/time.md)
STALL_WALL_S = 60.0
SPEED_SMOOTHING = 0.2  # weight of the latest tick in the speed a `SimClock` extrapolates with


M = TypeVar("M", bound=Message)
Reject = Callable[[str, str], None]  # a malformed input's key and reason, counted (Bus.reject)


class Stalled(RuntimeError):
    """Simulated time stood still: a loop the simulation holds for did not move on."""


def station_message(sample: zenoh.Sample, expected: type[M], reject: Reject) -> tuple[str, M] | None:
    """The station a testbed sample comes from and the `expected` message it carries; None,
    rejected with the reason, if it does not decode."""
    key = str(sample.key_expr)
    try:
        message = decode(key, sample.payload.to_bytes(), expected).message
    except BadMessage as exc:
        reject(key, exc.reason)
        return None
    return key.split("/")[2], message


class Clock:
    """The wall clock: `time.monotonic()` for periods and timeouts, `time.time()` for stamps."""

    mode = "real"

    def __init__(self) -> None:
        self._per_thread = threading.local()  # the named loop a thread runs, if any (`loop`)

    def loop(self) -> str | None:
        """The named loop the calling thread runs (it entered or waited on this clock), if any."""
        return getattr(self._per_thread, "loop", None)

    def _runs(self, loop: str) -> None:
        self._per_thread.loop = loop

    def now_s(self) -> float:
        """Seconds on this clock, for periods, ages and timeouts (no fixed origin)."""
        return time.monotonic()

    def stamp_s(self) -> float:
        """A message's stamp: when it was sent, comparable across the system's stations."""
        return time.time()

    def wait(self, event: threading.Event, timeout_s: float) -> bool:
        """Wait `timeout_s` of this clock's seconds, or until `event` is set: whether it is."""
        return event.wait(max(0.0, timeout_s))

    def wait_until(self, event: threading.Event, t_s: float) -> bool:
        """Wait until this clock reads `t_s`, or until `event` is set: whether it is."""
        return self.wait(event, t_s - self.now_s())

    def wall_timeout_s(self, timeout_s: float) -> float:
        """How long to block on the wall clock (a `Condition.wait`) before looking at this clock
        again, to wait `timeout_s` of its seconds."""
        return max(0.0, timeout_s)

    def done(self, loop: str, t_s: float) -> None:
        """`loop` has nothing to do before `t_s` (with `sim`, the simulation waits for it)."""

    def enter(self, loop: str, t_s: float, stop: threading.Event) -> None:
        """`loop` starts, its first tick at `t_s` (in lockstep it waits for its turn)."""
        self._runs(loop)
        self.done(loop, t_s)

    def sleep_until(self, loop: str, t_s: float, stop: threading.Event) -> bool:
        """`loop` waits for its tick at `t_s`: False once `stop` is set."""
        self._runs(loop)
        self.done(loop, t_s)
        return not self.wait_until(stop, t_s)

    def step_aside(self, t_s: float, stop: threading.Event) -> bool:
        """The calling thread's loop, if it runs one, has nothing to do before `t_s` (the
        simulation need not wait for it), and waits on this clock until then: a sender whose
        emulated link is full until `t_s`, when it next has room (linkemu.runner), or a loop whose
        bulk work (a render, a stereo match) lasts until then (`after_work`). True once there,
        False once `stop` is set or where the caller cannot wait (lockstep, outside a loop's
        turn)."""
        loop = self.loop()
        if loop is not None:
            self.done(loop, t_s)
        return not self.wait_until(stop, t_s)

    def after_work(self, started_s: float, latency_s: float, stop: threading.Event) -> bool:
        """Bulk work a loop started at `started_s` (in a process or thread of its own, from inputs
        taken then) is done `latency_s` later on a simulated clock, however long it takes in wall
        time: the loop steps aside until then, so that the simulation and the other loops go on
        meanwhile and its result comes out on the same period whatever the machine's load. On the
        wall clock it is done when it is done: at once. False once `stop` is set."""
        if self.mode == "real" or latency_s <= 0:
            return not stop.is_set()
        return self.step_aside(started_s + latency_s, stop)


WALL = Clock()


class SimClock(Clock):
    """The simulation's time, from its ticks, extrapolated between two ticks at the speed seen so
    far but never past `horizon_s` after the latest (one control period: never past the next
    tick), so that it never runs ahead of the simulation nor goes back; with `horizon_s` 0 (`--speed
    max`) it moves in whole periods, as lockstep's does. Before the first tick it stands at 0: the
    stations' loops wait for the simulation to start. A wait on it is woken by the tick that ends
    it (and the conditions given to `wake_on_tick` are notified on every tick), not by polling."""

    mode = "sim"

    def __init__(self, horizon_s: float, speed: float = 1.0) -> None:
        super().__init__()
        self.horizon_s = horizon_s
        self.speed = speed if math.isfinite(speed) else 1.0  # simulated seconds per wall second, as seen
        self._fixed_speed = math.isfinite(speed)
        self._tick_s = 0.0
        self._tick_wall_s: float | None = None
        self._latest_s = 0.0
        self._lock = threading.Lock()
        self._ticked = threading.Condition()  # notified on every tick
        self._woken: list[threading.Condition] = []  # others' conditions, notified on every tick
        self._loops: dict[str, float] = {}  # done up to, per loop [sim s]
        self.on_progress: Callable[[float], None] | None = None  # the slowest loop moved on

    def tick(self, sim_time_s: float) -> None:
        wall_s = time.monotonic()
        with self._lock:
            if sim_time_s <= self._tick_s and self._tick_wall_s is not None:
                return  # late or repeated
            if not self._fixed_speed and self._tick_wall_s is not None and wall_s > self._tick_wall_s:
                seen = (sim_time_s - self._tick_s) / (wall_s - self._tick_wall_s)
                self.speed += SPEED_SMOOTHING * (seen - self.speed)
            self._tick_s, self._tick_wall_s = sim_time_s, wall_s
        for condition in (self._ticked, *self._woken):
            with condition:
                condition.notify_all()

    def wake_on_tick(self, condition: threading.Condition) -> None:
        """Notify `condition` on every tick (a thread that waits on it for this clock's time)."""
        self._woken.append(condition)

    def now_s(self) -> float:
        with self._lock:
            if self._tick_wall_s is not None:
                ahead_s = min((time.monotonic() - self._tick_wall_s) * self.speed, self.horizon_s)
                self._latest_s = max(self._latest_s, self._tick_s + ahead_s)
            return self._latest_s

    def stamp_s(self) -> float:
        return self.now_s()

    def wait(self, event: threading.Event, timeout_s: float) -> bool:
        return self.wait_until(event, self.now_s() + timeout_s)

    def wait_until(self, event: threading.Event, t_s: float) -> bool:
        """Until the time reads `t_s` itself, not for a span from a reading: a loop that said it
        is done up to `t_s` took the span from one reading and the deadline from the next, so
        ticks that landed between the two put its wake-up past `t_s`, on a tick the simulation,
        held back for that loop, never sent (simulated time stood still)."""
        with self._ticked:
            while not event.is_set() and (remaining_s := t_s - self.now_s()) > 0:
                self._ticked.wait(self.wall_timeout_s(remaining_s))
        return event.is_set()

    def wall_timeout_s(self, timeout_s: float) -> float:
        """Until the time extrapolated at the speed asked gets there (a tick wakes the waiter
        sooner), at most GUARD_WALL_S; with no extrapolation, only a tick moves the time."""
        if self.horizon_s > 0 and self._fixed_speed:
            return min(max(0.0, timeout_s) / self.speed, GUARD_WALL_S)
        return GUARD_WALL_S

    def progress_s(self) -> float:
        """How far every loop on this clock is done (the slowest's next tick)."""
        with self._lock:
            return min(self._loops.values(), default=math.inf)

    def slowest(self) -> tuple[str, float] | None:
        """The loop least far done, and how far (None: no loop yet)."""
        with self._lock:
            return min(self._loops.items(), key=lambda item: item[1], default=None)

    def done(self, loop: str, t_s: float) -> None:
        with self._lock:
            before = min(self._loops.values(), default=-math.inf)
            self._loops[loop] = t_s
            after = min(self._loops.values())
        if after > before and self.on_progress is not None:
            self.on_progress(after)


def follow(session: zenoh.Session, system: str, clock: SimClock) -> zenoh.Subscriber:
    """Tick `clock` with the simulation's time (a malformed tick is dropped and logged once)."""
    key = keys.clock_key(system)
    logged: list[str] = []

    def on_tick(sample: zenoh.Sample) -> None:
        try:
            message = decode(key, sample.payload.to_bytes(), SimTime).message
        except BadMessage as exc:
            if not logged:
                logged.append(exc.reason)
                log.warning("dropped a clock tick: %s", exc.reason)
            return
        clock.tick(message.sim_time_s)

    return session.declare_subscriber(key, on_tick)


class ProgressReport:
    """Publishes how far a station's loops are done each time the slowest moves on, and again
    every `REPEAT_WALL_S` (a simulation that starts later hears it; a silent station is dead)."""

    REPEAT_WALL_S = 0.5

    def __init__(self, session: zenoh.Session, system: str, station: str, clock: SimClock) -> None:
        self._publisher = session.declare_publisher(
            keys.progress_key(system, station), congestion_control=zenoh.CongestionControl.BLOCK, express=True
        )
        self._lock = threading.Lock()
        self._seq = 0
        self._latest_s = 0.0
        self._stop = threading.Event()
        self._clock = clock
        clock.on_progress = self.publish
        self._thread = threading.Thread(target=self._repeat, name="progress", daemon=True)
        self._thread.start()

    def publish(self, t_s: float) -> None:
        with self._lock:
            self._latest_s = max(0.0, t_s)
            self._publisher.put(encode(SimTime(sim_time_s=self._latest_s), self._seq, time.time()))
            self._seq += 1

    def _repeat(self) -> None:
        stood: tuple[str, float] | None = None
        since_wall_s, warned = time.monotonic(), False
        while not self._stop.wait(self.REPEAT_WALL_S):
            self.publish(self._latest_s)
            slowest = self._clock.slowest()
            if slowest != stood:
                stood, since_wall_s, warned = slowest, time.monotonic(), False
            elif (
                stood is not None
                and not warned
                and self._clock.now_s() >= stood[1]
                and time.monotonic() - since_wall_s > STALL_WALL_S / 2
            ):
                warned = True  # its tick has come, and it has not moved on: the loop to look at
                log.warning(
                    "loop %s done up to %.3f s and no further for %.0f s while the clock reads %.3f s",
                    *stood,
                    STALL_WALL_S / 2,
                    self._clock.now_s(),
                )

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1.0)
        self._publisher.undeclare()


class Holdback:
    """What the simulation waits for before it steps past t: every station of `stations` done with
    t - `max_lag_s` (each reports on its progress key). A station not heard from yet is waited for
    up to `start_wall_s` (it is starting; then it is not part of the run, with a warning); one
    whose liveliness token goes (its process died) is let go at once, so that a dead station stalls
    nothing, and waited for again from its next report (restarted). Nothing else is let go: a
    station, or the simulation's own loops, whose progress stands still while the simulation holds
    for it (silent, or repeating the same report) is named in the log after `silent_wall_s`, and
    past STALL_WALL_S the run fails (`Stalled`), naming it and where it stood: a run on simulated
    time whose verdict depended on how long a loop stood on a loaded machine would not repeat.
    `held_wall_s`: the wall time the simulation waited on each, the station that limited the
    speed."""

    def __init__(
        self,
        session: zenoh.Session,
        system: str,
        stations: Iterable[str],
        max_lag_s: float,
        reject: Reject,
        start_wall_s: float = 60.0,
        silent_wall_s: float = 5.0,
    ) -> None:
        self.max_lag_s = max_lag_s
        self.start_wall_s, self.silent_wall_s = start_wall_s, silent_wall_s
        self.stations = set(stations)
        self.progress_s: dict[str, float] = {}
        self.heard_wall_s: dict[str, float] = {}
        self.held_wall_s: dict[str, float] = dict.fromkeys(["simulation", *sorted(self.stations)], 0.0)
        self.let_go: set[str] = set()  # dead, or never heard from at the start
        self._stood: tuple[str, float, float, bool] | None = None  # who, done up to, since [wall s], named
        self.reject = reject
        self._started_wall_s = time.monotonic()
        self._cond = threading.Condition()
        self._subscriber = session.declare_subscriber(keys.progress_key(system, "*"), self._on_progress)
        self._alive = session.liveliness().declare_subscriber(keys.alive_key(system, "*"), self._on_alive)

    def _on_alive(self, sample: zenoh.Sample) -> None:
        station = str(sample.key_expr).split("/")[2]
        if sample.kind != zenoh.SampleKind.DELETE or station not in self.stations:
            return
        with self._cond:
            self.let_go.add(station)
            self.progress_s.pop(station, None)  # a restarted station reports afresh
            self._cond.notify_all()
        log.warning("%s is gone: the simulation no longer waits for it", station)

    def _on_progress(self, sample: zenoh.Sample) -> None:
        got = station_message(sample, SimTime, self.reject)
        if got is None:
            return
        station, message = got
        with self._cond:
            if station not in self.stations:
                return
            self.progress_s[station] = max(self.progress_s.get(station, -math.inf), message.sim_time_s)
            self.heard_wall_s[station] = time.monotonic()
            if station in self.let_go:
                self.let_go.discard(station)
                log.info("%s reports its progress again; the simulation waits for it again", station)
            self._cond.notify_all()

    def _laggard(self, t_s: float, now_wall_s: float, own: SimClock) -> str | None:
        """The station furthest behind t - max_lag_s (the simulation: its own cameras and sonar),
        letting go of those never heard from at the start."""
        if own.progress_s() < t_s - self.max_lag_s:
            return "simulation"
        behind = [
            s for s in self.stations - self.let_go if self.progress_s.get(s, -math.inf) < t_s - self.max_lag_s
        ]
        for station in behind:
            if station not in self.heard_wall_s and now_wall_s - self._started_wall_s > self.start_wall_s:
                self.let_go.add(station)
                log.warning(
                    "%s not heard from in %.0f s: the simulation runs without it", station, self.start_wall_s
                )
        behind = [s for s in behind if s not in self.let_go]
        return min(behind, key=lambda s: self.progress_s.get(s, -math.inf)) if behind else None

    def hold(
        self, t_s: float, stop: threading.Event, own: SimClock, waiting: Callable[[], None] = lambda: None
    ) -> None:
        """Block until every station, and every loop of the simulation's `own` clock, is done with
        `t_s` - max_lag_s (or `stop`); `waiting` is called every REPEAT_WALL_S meanwhile (the
        simulation tells its time again, for a station that joins while it waits). `Stalled` if
        the one it holds for stands still for STALL_WALL_S."""
        repeat_s = time.monotonic() + ProgressReport.REPEAT_WALL_S
        with self._cond:
            while not stop.is_set():
                now_wall_s = time.monotonic()
                laggard = self._laggard(t_s, now_wall_s, own)
                if laggard is None:
                    return
                self._watch(laggard, t_s, now_wall_s, own)
                if now_wall_s >= repeat_s:
                    waiting()
                    repeat_s = now_wall_s + ProgressReport.REPEAT_WALL_S
                self._cond.wait(GUARD_WALL_S)  # woken by a report (notify), or to look at the time
                self.held_wall_s[laggard] += time.monotonic() - now_wall_s

    def _watch(self, laggard: str, t_s: float, now_wall_s: float, own: SimClock) -> None:
        """Name a laggard that stands still past `silent_wall_s`; past STALL_WALL_S, fail."""
        if laggard == "simulation":
            slowest = own.slowest()
            who, done_s = (
                (f"the simulation's loop {slowest[0]}", slowest[1]) if slowest else (laggard, -math.inf)
            )
        else:
            who, done_s = laggard, self.progress_s.get(laggard, -math.inf)
        if done_s == -math.inf:
            return  # not heard yet: starting (start_wall_s)
        if self._stood is None or self._stood[:2] != (who, done_s):
            self._stood = (who, done_s, now_wall_s, False)
            return
        stood_s = now_wall_s - self._stood[2]
        where = (
            f"{who} done up to {done_s:.3f} s and no further for {stood_s:.1f} s "
            f"while the simulation held at {t_s:.3f} s"
        )
        if stood_s > STALL_WALL_S:
            raise Stalled(f"simulated time stood still: {where} (its log names the loop)")
        if stood_s > self.silent_wall_s and not self._stood[3]:
            self._stood = (*self._stood[:3], True)
            log.warning("%s", where)

    def notify(self) -> None:
        """Something `hold` waits for may have come (the simulation's own loops moved on)."""
        with self._cond:
            self._cond.notify_all()

    def status(self) -> dict[str, float]:
        with self._cond:
            return {s: round(held, 3) for s, held in self.held_wall_s.items()}

    def close(self) -> None:
        self._subscriber.undeclare()
        self._alive.undeclare()
