"""Simulated time (timing.clock): the clock the stations follow, the loops on it, the emulated
links on it, and what the simulation waits for. Real threads and real Zenoh sessions; a thread
stands for the simulation and ticks the clock."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from abyss.bus.session import open_session, zenoh_config
from abyss.common.errors import ConfigError
from abyss.common.ports import free_port
from abyss.config import load
from abyss.config.linkprofile import profile
from abyss.interface import keys
from abyss.linkemu.runner import LinkRunner
from abyss.timing import clock as clock_module
from abyss.timing.clock import Clock, Holdback, ProgressReport, SimClock
from abyss.timing.lockstep import LockstepClock
from abyss.timing.rate import Rate

PERIOD_S = 0.05  # the simulation's control period: its ticks' spacing


class Ticker:
    """The simulation's part: ticks `clock` every PERIOD_S simulated seconds at `speed`."""

    def __init__(self, clock: SimClock, speed: float) -> None:
        self.clock, self.speed = clock, speed
        self.stop = threading.Event()
        self.sim_s = 0.0
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self.stop.wait(PERIOD_S / self.speed):
            self.sim_s += PERIOD_S
            self.clock.tick(self.sim_s)

    def close(self) -> None:
        self.stop.set()
        self.thread.join()


@pytest.fixture
def ticking() -> Iterator[tuple[SimClock, Ticker]]:
    clock = SimClock(PERIOD_S, speed=4.0)
    ticker = Ticker(clock, 4.0)
    yield clock, ticker
    ticker.close()


def test_the_clock_stands_until_the_first_tick_then_never_runs_past_the_next() -> None:
    clock = SimClock(PERIOD_S, speed=4.0)
    assert clock.now_s() == 0.0
    time.sleep(0.05)
    assert clock.now_s() == 0.0  # no simulation yet: the stations' loops wait
    clock.tick(1.0)
    time.sleep(0.1)  # at speed 4, 0.4 s would have passed; the horizon is one period
    assert clock.now_s() == pytest.approx(1.0 + PERIOD_S)
    clock.tick(0.5)  # a late tick never takes the clock back
    assert clock.now_s() >= 1.0 + PERIOD_S
    clock.tick(1.05)
    assert clock.now_s() >= 1.05  # the new tick at once, never back
    time.sleep(0.1)
    assert clock.now_s() == pytest.approx(1.05 + PERIOD_S)  # and again no further than one period on


def test_a_wait_on_simulated_time_lasts_its_share_of_wall_time(ticking: tuple[SimClock, Ticker]) -> None:
    clock, _ = ticking
    stop = threading.Event()
    start_s, wall0 = clock.now_s(), time.monotonic()
    assert not clock.wait(stop, 1.0)
    waited_wall_s = time.monotonic() - wall0
    assert clock.now_s() - start_s >= 1.0
    assert 0.2 <= waited_wall_s < 0.6  # 1 simulated s at speed 4, give or take a tick
    threading.Timer(0.05, stop.set).start()
    wall0 = time.monotonic()
    assert clock.wait(stop, 100.0)  # a set event ends the wait at once
    assert time.monotonic() - wall0 < 1.0


def test_a_named_loop_on_simulated_time_keeps_its_period_and_says_how_far_it_is(
    ticking: tuple[SimClock, Ticker],
) -> None:
    clock, _ = ticking
    stop = threading.Event()
    reported: list[float] = []
    clock.on_progress = reported.append
    rate = Rate(0.1, stop, clock, "control")
    ticks_at_s = []
    wall0 = time.monotonic()
    for _ in range(10):
        assert rate.sleep()
        ticks_at_s.append(clock.now_s())
    wall_s = time.monotonic() - wall0
    assert np.diff(ticks_at_s) == pytest.approx([0.1] * 9, abs=0.03)  # simulated seconds
    assert wall_s < 0.6  # 1 simulated s at speed 4
    assert clock.progress_s() == pytest.approx(reported[-1])
    # each time it waits, the tick it waits for: the last one, the tick it then woke at
    assert reported == sorted(reported) and reported[-1] == pytest.approx(1.0)
    assert reported[-1] <= ticks_at_s[-1] < reported[-1] + 0.1


def test_at_max_speed_the_time_moves_on_ticks_alone_and_each_wakes_what_waits_for_it(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """`--speed max`: whole periods, no extrapolation; a wait (a loop's, an emulated link's) is
    ended by the tick that reaches it, not found by polling: with the guard set to a minute,
    only a tick can wake them."""
    monkeypatch.setattr("abyss.timing.clock.GUARD_WALL_S", 60.0)
    clock = SimClock(0.0, speed=float("inf"))
    stop = threading.Event()
    clock.tick(1.0)
    time.sleep(0.1)
    assert clock.now_s() == 1.0  # no extrapolation between ticks
    woke: list[float] = []

    def wait_a_tenth() -> None:  # of a simulated second, as a loop does
        clock.wait(stop, 0.1)
        woke.append(clock.now_s())

    waiter = threading.Thread(target=wait_a_tenth, daemon=True)
    waiter.start()
    delivered: list[float] = []
    runner = LinkRunner(
        "tether", profile("tether"), lambda _tag, _payload: delivered.append(clock.now_s()),
        np.random.default_rng(1), clock=clock,
    )  # fmt: skip
    try:
        runner.send(b"x" * 100, block=True, tag=0)  # due 90-110 ms on
        clock.tick(1.05)
        time.sleep(0.3)
        assert not woke and not delivered  # neither is due at 1.05
        clock.tick(1.15)
        waiter.join(5.0)
        deadline = time.monotonic() + 5.0
        while not delivered and time.monotonic() < deadline:
            time.sleep(0.01)
        assert woke == [1.15] and delivered == [1.15]  # each on the tick that reached it
    finally:
        stop.set()
        runner.close()


def test_a_loop_wakes_at_the_tick_it_said_however_many_ticks_land_while_it_reads_the_time() -> None:
    """The simulation steps from t once every loop is done with t - max_lag (Holdback), so a loop
    that said it is done up to T must wake on the ticks that reach T. Here the simulation steps as
    far as that lets it right after the loop reads the time following its report (its thread
    descheduled there, as on a loaded machine): a wait measured as a span from one reading and
    ended from another went past T, for a tick the simulation, held for the loop, never sent
    (valve-seized stood still at 37 s at --speed max)."""
    max_lag_s = 0.1
    clock = SimClock(0.0, speed=float("inf"))
    clock.tick(1.0)
    stop = threading.Event()
    rate = Rate(PERIOD_S, stop, clock, "control")
    reported: list[float] = []
    clock.on_progress = reported.append
    read = clock.now_s
    sim = [1.0]

    def now_s() -> float:  # the loop reads the time; the simulation's ticks land just after
        value = read()
        if reported:
            reported.clear()
            while clock.progress_s() >= sim[0] - max_lag_s:  # Holdback's rule, held for the loop
                sim[0] = round(sim[0] + PERIOD_S, 9)
                clock.tick(sim[0])
        return value

    clock.now_s = now_s  # type: ignore[method-assign]
    woke: list[bool] = []
    loop = threading.Thread(target=lambda: woke.append(rate.sleep()), daemon=True)
    loop.start()
    loop.join(3.0)
    stop.set()
    loop.join(1.0)
    assert clock.progress_s() == pytest.approx(1.05)  # it said: done up to 1.05
    assert sim[0] == pytest.approx(1.2)  # the simulation went as far as that lets it, no further
    assert woke == [True]  # and the loop woke there, its tick reached, before anyone stopped it


def test_an_emulated_link_on_simulated_time_delays_by_its_profile_in_simulated_time(
    ticking: tuple[SimClock, Ticker],
) -> None:
    """The tether (100 ms +- 10 ms) at speed 4: the delays, measured in simulated time, are the
    profile's; on the wall clock they last a quarter of that."""
    clock, _ = ticking
    delivered: list[tuple[float, float]] = []  # (sent, delivered) on the wall clock
    sent_wall_s: dict[int, float] = {}
    tether = profile("tether")
    runner = LinkRunner(
        "tether",
        tether,
        lambda tag, _payload: delivered.append((sent_wall_s[tag], time.monotonic())),
        np.random.default_rng(1),
        clock=clock,
    )
    try:
        for i in range(40):
            sent_wall_s[i] = time.monotonic()
            assert runner.send(b"x" * 100, block=False, tag=i)
            time.sleep(0.01)
        deadline = time.monotonic() + 5.0
        while len(delivered) < 40 and time.monotonic() < deadline:
            time.sleep(0.01)
        stats = runner.snapshot()
    finally:
        runner.close()
    assert len(delivered) == 40
    assert 85 <= stats["delay_p50_ms"] <= 125, stats  # simulated time, the link's own
    wall_ms = np.median([(d - s) * 1e3 for s, d in delivered])
    assert 15 <= wall_ms <= 60, wall_ms  # about 100 ms / 4


@pytest.fixture
def sessions() -> Iterator[tuple[object, object]]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    simulation = open_session(zenoh_config([endpoint], mode="router"), "simulation")
    station = open_session(zenoh_config([], [endpoint], mode="peer"), "station")
    yield simulation, station
    station.close()
    simulation.close()


def test_the_simulation_waits_for_the_slowest_station_and_lets_a_silent_one_go(sessions) -> None:  # type: ignore[no-untyped-def]
    simulation, station = sessions
    own = SimClock(PERIOD_S)  # the simulation's own loops (none here)
    rejected: list[tuple[str, str]] = []
    got_bad = threading.Event()
    holdback = Holdback(
        simulation,
        "sys",
        ["onboard", "vessel"],
        max_lag_s=0.1,
        reject=lambda key, reason: (rejected.append((key, reason)), got_bad.set()),
        start_wall_s=0.5,
        silent_wall_s=0.5,
    )
    onboard_clock = SimClock(PERIOD_S)
    report = ProgressReport(station, "sys", "onboard", onboard_clock)
    stop = threading.Event()
    try:
        onboard_clock.done("control", 1.0)
        wall0 = time.monotonic()
        holdback.hold(1.0, stop, own)  # onboard is at 1.0; vessel never speaks: let go after 0.5 s
        assert 0.4 <= time.monotonic() - wall0 < 3.0
        assert set(holdback.let_go) == {"vessel"}
        released = threading.Event()

        def hold_then_say() -> None:
            holdback.hold(2.0, stop, own)  # onboard is behind 2.0 - 0.1
            released.set()

        threading.Thread(target=hold_then_say, daemon=True).start()
        assert not released.wait(0.3)
        onboard_clock.done("control", 1.95)
        assert released.wait(2.0)
        assert holdback.status()["onboard"] >= 0.25  # the wall time it held the simulation
        station.put(keys.progress_key("sys", "onboard"), b"\x00garbage")  # counted as the bus counts
        assert got_bad.wait(5.0)
        assert rejected[0][0] == keys.progress_key("sys", "onboard") and rejected[0][1]
        assert holdback.progress_s["onboard"] >= 1.95  # and nothing it knew is lost
    finally:
        stop.set()
        report.close()
        holdback.close()


def test_a_laggard_that_stands_still_is_named_then_fails_the_run_and_a_dead_one_is_let_go(  # type: ignore[no-untyped-def]
    sessions, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """A station that keeps saying the same progress, or the simulation's own loops standing
    still, is never let go (the run would go on without it, its result the machine's load's): it
    is named after `silent_wall_s`, and past STALL_WALL_S the run fails naming it and where it
    stood. A station whose process dies is let go at once, and waited for again once it reports."""
    monkeypatch.setattr(clock_module, "STALL_WALL_S", 1.0)
    simulation, station = sessions
    own = SimClock(PERIOD_S)
    holdback = Holdback(
        simulation, "sys", ["onboard"], max_lag_s=0.1, reject=lambda key, reason: None, silent_wall_s=0.3
    )
    onboard_clock = SimClock(PERIOD_S)
    report = ProgressReport(station, "sys", "onboard", onboard_clock)  # it repeats: never silent
    stop = threading.Event()
    try:
        onboard_clock.done("control", 1.0)
        own.done("cameras", 3.0)
        wall0 = time.monotonic()
        with pytest.raises(clock_module.Stalled) as stalled:
            holdback.hold(1.5, stop, own)  # onboard stands at 1.0 < 1.5 - 0.1
        assert 0.9 <= time.monotonic() - wall0 < 4.0 and not holdback.let_go
        assert "onboard done up to 1.000 s and no further" in str(stalled.value)
        assert "while the simulation held at 1.500 s" in str(stalled.value)
        assert any("onboard done up to 1.000 s" in r.getMessage() for r in caplog.records)  # named first
        onboard_clock.done("control", 4.0)
        with pytest.raises(clock_module.Stalled, match=r"the simulation's loop cameras done up to 3\.000 s"):
            holdback.hold(3.5, stop, own)  # onboard is past it; the simulation's cameras are not
        own.done("cameras", 4.0)
        holdback.hold(3.5, stop, own)  # both past: no wait, no failure
        liveliness = station.liveliness().declare_token(keys.alive_key("sys", "onboard"))
        time.sleep(0.2)
        liveliness.undeclare()  # its process died: its token goes
        deadline = time.monotonic() + 5.0
        while "onboard" not in holdback.let_go and time.monotonic() < deadline:
            time.sleep(0.05)
        assert holdback.let_go == {"onboard"}
        own.done("cameras", 9.0)
        wall0 = time.monotonic()
        holdback.hold(9.0, stop, own)  # onboard stands at 4.0, gone: not waited for
        assert time.monotonic() - wall0 < 0.5
    finally:
        stop.set()
        report.close()
        holdback.close()


class Simulation:
    """The simulation's part at `--speed max`: it steps one period at a time as far as the
    holdback's rule lets it (every loop of `clock` done with t - max_lag), up to `end_s`."""

    def __init__(self, clock: SimClock, end_s: float, max_lag_s: float = 0.1) -> None:
        self.clock, self.end_s, self.max_lag_s = clock, end_s, max_lag_s
        self.sim_s = 0.0
        self.moved = threading.Condition()
        clock.on_progress = lambda _t_s: self._notify()
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _notify(self) -> None:
        with self.moved:
            self.moved.notify_all()

    def _run(self) -> None:
        self.clock.tick(0.0)
        while self.sim_s < self.end_s - 1e-9 and not self.stop.is_set():
            with self.moved:
                if self.clock.progress_s() < self.sim_s - self.max_lag_s:
                    self.moved.wait(0.05)
                    continue
            self.sim_s = round(self.sim_s + PERIOD_S, 9)
            self.clock.tick(self.sim_s)

    def close(self) -> None:
        self.stop.set()
        self.thread.join(5.0)


def storm_link(clock: SimClock, stop: threading.Event) -> LinkRunner:
    """The satellite in a storm (256 kbit/s, TCP backing off after bursts of loss) on `clock`."""
    return LinkRunner(
        "satellite", profile("satellite-storm"), lambda _tag, _payload: None, np.random.default_rng(3),
        stopping=stop, clock=clock,
    )  # fmt: skip


def relay(
    clock: SimClock,
    link: LinkRunner,
    stop: threading.Event,
    accepted: list[float],
    turns: list[tuple[float, str]],
) -> None:
    """The vessel's relay towards shore in a storm: each 0.1 s, 24 kB for a 256 kbit/s link (3.2 kB
    a tick), every message reliable (Zenoh's BLOCK): when each was taken, and its ticks."""
    rate = Rate(0.1, stop, clock, "relay")
    while rate.sleep():
        turns.append((clock.now_s(), "relay"))
        for _ in range(3):
            if link.send(b"x" * 8000, block=True, tag="relay"):
                accepted.append(clock.now_s())


def test_a_sender_on_a_full_link_waits_on_simulated_time_so_simulated_time_never_stands_still() -> None:
    """satellite-storm at --speed max stood still: the vessel's relay blocked on the satellite's full
    queue, polling in wall time; the queue drains only as simulated time advances, and simulated
    time waited for that very loop. The sender now waits on the clock, for the time the link says
    room comes, and its loop is done until then: 20 simulated seconds pass, nothing dropped."""
    clock = SimClock(0.0, speed=float("inf"))
    stop = threading.Event()
    link = storm_link(clock, stop)
    accepted: list[float] = []
    sender = threading.Thread(target=relay, args=(clock, link, stop, accepted, []), daemon=True)
    sender.start()
    while clock.slowest() is None:  # the loop is there before the simulation starts
        time.sleep(0.01)
    simulation = Simulation(clock, end_s=20.0)
    try:
        deadline = time.monotonic() + 60.0
        while simulation.thread.is_alive() and time.monotonic() < deadline:
            simulation.thread.join(0.1)
        reached_s = simulation.sim_s
    finally:
        stop.set()
        simulation.close()
        sender.join(5.0)
        link.close()
    assert reached_s == pytest.approx(20.0), f"simulated time stood still at {reached_s:.2f} s"
    assert link.snapshot()["messages_dropped"] == 0  # reliable: none dropped, the sender waited
    assert len(accepted) >= 10 and accepted[-1] > 5.0  # and went on as room came (TCP backs off in bursts)


def run_lockstep_relay(periods: int) -> tuple[list[float], list[tuple[float, str]], dict[str, float]]:
    """The relay above in lockstep, with a second loop beside it: (when each message was taken,
    the loops' turns in order, the link's counters)."""
    clock = LockstepClock()
    stop = threading.Event()
    link = storm_link(clock, stop)
    accepted: list[float] = []
    turns: list[tuple[float, str]] = []

    def other() -> None:
        rate = Rate(0.1, stop, clock, "status")
        while rate.sleep():
            turns.append((clock.now_s(), "status"))

    threads = [
        threading.Thread(target=other, daemon=True),
        threading.Thread(target=relay, args=(clock, link, stop, accepted, turns), daemon=True),
    ]
    for thread in threads:
        thread.start()
    while clock.loops() != {"relay", "status"}:
        time.sleep(0.01)
    try:
        for period in range(1, periods + 1):
            t_s = round(period * PERIOD_S, 9)
            clock.set_period(t_s)
            link.deliver_due(t_s)
            clock.run_loops(t_s, stop)
    finally:
        stop.set()
        for thread in threads:
            thread.join(2.0)
        link.close()
    return accepted, turns, link.snapshot()


def test_in_lockstep_a_sender_on_a_full_link_goes_on_in_the_period_it_has_room_the_same_every_run() -> None:
    """A reliable key means the same in every time mode: in lockstep the relay that finds the
    queue full hands its turn back and goes on when the link has room, the other loop and the
    periods in between running meanwhile; nothing is dropped, and two runs agree exactly."""
    accepted, turns, counters = run_lockstep_relay(200)
    assert counters["messages_dropped"] == 0 and len(accepted) >= 20
    assert np.all(np.diff(accepted) >= 0) and accepted[-1] > 5.0  # held back by the link
    status = [t for t, loop in turns if loop == "status"]
    assert status == pytest.approx([0.1 * k for k in range(1, 101)])  # the other loop never missed a turn
    assert len([loop for _, loop in turns if loop == "relay"]) < 100  # the relay's blocked ticks went by
    assert run_lockstep_relay(200) == (accepted, turns, counters)


@pytest.mark.parametrize(
    ("items", "field", "reason"),
    [
        (["time.mode=fast"], "time.mode", "not one of real, sim"),
        (["time.mode=sim", "time.speed=0"], "time.speed", "a number from 0.01 to 1000, or max"),
        (["time.mode=sim", "time.speed=quick"], "time.speed", "or max"),
        (["time.speed=4"], "time.speed", "only with time.mode sim"),
        (["time.mode=sim", 'time.stations=["simulation"]'], "time.stations", "not one of"),
        (["time.mode=sim", "ros2.station=onboard"], "time.mode", "runs on the wall clock"),
    ],
)
def test_a_bad_time_source_fails_at_start_naming_the_field(items: list[str], field: str, reason: str) -> None:
    with pytest.raises(ConfigError) as caught:
        load(None, items)
    assert caught.value.field == field and reason in caught.value.reason


def test_speed_max_is_infinite_and_real_time_is_one() -> None:
    assert load(None, ["time.mode=sim", "time.speed=max"]).time.speed_factor == float("inf")
    assert load(None, []).time.speed_factor == 1.0


def test_lockstep_runs_the_loops_due_one_at_a_time_in_name_order() -> None:
    clock = LockstepClock()
    stop = threading.Event()
    ran: list[tuple[str, float]] = []
    inside = [0]

    def loop(name: str, period_s: float) -> None:
        rate = Rate(period_s, stop, clock, name)
        while rate.sleep():
            inside[0] += 1
            assert inside[0] == 1  # alone
            ran.append((name, clock.now_s()))
            time.sleep(0.01)  # a thread left to itself would overlap the next loop here
            inside[0] -= 1

    threads = [
        threading.Thread(target=loop, args=args, daemon=True)
        for args in (("sonar", 0.1), ("control", 0.05), ("perception", 0.05))
    ]
    for thread in threads:
        thread.start()
    while clock.loops() != {"sonar", "control", "perception"}:
        time.sleep(0.01)
    for period in range(1, 5):
        clock.set_period(period * 0.05)
        clock.run_loops(period * 0.05, stop)
    stop.set()
    assert [name for name, _ in ran] == [
        "control",
        "perception",
        "control",
        "perception",
        "sonar",
        "control",
        "perception",
        "control",
        "perception",
        "sonar",
    ]
    assert [t for name, t in ran if name == "sonar"] == pytest.approx([0.1, 0.2])


def test_in_lockstep_room_due_a_hair_past_the_period_is_waited_for_in_the_next_one() -> None:
    """Room the link says is due a float's rounding past this period (a serialisation end summed
    otherwise than the periods) is not this period's: the sender goes on in the next one, not in
    this one again, where the link has no room yet and it would ask for ever."""
    clock = LockstepClock()
    stop = threading.Event()
    resumed: list[float] = []

    def sender() -> None:
        rate = Rate(PERIOD_S, stop, clock, "relay")
        while rate.sleep():  # a loop: each turn handed back as it waits
            if not resumed and clock.step_aside(clock.now_s() + 1e-9, stop):
                resumed.append(clock.now_s())

    thread = threading.Thread(target=sender, daemon=True)
    thread.start()
    while clock.loops() != {"relay"}:
        time.sleep(0.01)
    try:
        for period in range(1, 4):
            clock.set_period(period * PERIOD_S)
            clock.run_loops(period * PERIOD_S, stop)
    finally:
        stop.set()
        thread.join(2.0)
    assert resumed == [pytest.approx(2 * PERIOD_S)]


def bulk_loop(
    clock: Clock,
    stop: threading.Event,
    latency_s: float,
    gates: dict[float, threading.Event],
    log: list[tuple],
) -> None:
    """A sensor's loop with bulk work, as the simulation's cameras run it: each second it takes its
    input, hands the work to a thread of its own and steps aside for `latency_s`
    (`Clock.after_work`). The work ends only once its gate opens (or 5 s pass), and says whether
    it did; the loop logs when it took the input, the work's result and when it sent it."""
    with ThreadPoolExecutor(1) as worker:
        rate = Rate(1.0, stop, clock, "cameras")
        while rate.sleep():
            taken_s = clock.now_s()
            gate = gates.setdefault(round(taken_s, 6), threading.Event())
            work = worker.submit(lambda t=taken_s, g=gate: (g.wait(5.0), round(t * 10)))
            if not clock.after_work(taken_s, latency_s, stop):
                return
            log.append(("cameras", taken_s, work.result()))
            log.append(("sent", clock.now_s(), None))


def test_in_lockstep_bulk_work_runs_while_the_periods_go_on_and_its_result_goes_out_on_its_latency() -> None:
    """Bulk work (a render, a stereo match) ran inside its loop's turn, and the whole system waited
    for it each time. Now its loop steps aside for its latency of simulated time while the work
    runs in a thread of its own, the other loops running the periods in between meanwhile: here
    the work cannot end before the control loop has run the period before the result is due (its
    gate), which, were the periods waiting for the work, would never come. The result goes out
    on the period `latency_s` after the input was taken, the same every run."""

    def run() -> list[tuple]:
        clock, stop = LockstepClock(), threading.Event()
        log: list[tuple] = []
        gates: dict[float, threading.Event] = {}

        def control() -> None:
            rate = Rate(PERIOD_S, stop, clock, "control")
            while rate.sleep():
                log.append(("control", clock.now_s(), None))
                taken_s = round(clock.now_s() - 0.15, 6)  # the period before the result is due
                gates.setdefault(taken_s, threading.Event()).set()

        threads = [
            threading.Thread(target=bulk_loop, args=(clock, stop, 0.2, gates, log), daemon=True),
            threading.Thread(target=control, daemon=True),
        ]
        for thread in threads:
            thread.start()
        while clock.loops() != {"cameras", "control"}:
            time.sleep(0.01)
        try:
            for period in range(1, 45):
                clock.set_period(round(period * PERIOD_S, 9))
                clock.run_loops(round(period * PERIOD_S, 9), stop)
        finally:
            stop.set()
            for thread in threads:
                thread.join(2.0)
        return log

    log = run()
    results = [(t, result) for what, t, result in log if what == "cameras"]
    # each work's gate opened (the periods went on beside it), its result that of its input
    assert results == [(pytest.approx(1.0), (True, 10)), (pytest.approx(2.0), (True, 20))]
    assert [t for what, t, _ in log if what == "sent"] == pytest.approx([1.2, 2.2])  # its latency after
    control = [t for what, t, _ in log if what == "control"]
    assert control == pytest.approx([PERIOD_S * k for k in range(1, 45)])  # never a turn missed
    assert run() == log  # the same every run, turn for turn


def test_on_simulated_time_bulk_work_frees_the_simulation_till_its_latency_the_wall_clock_adds_none() -> None:
    """On simulated time the loop with bulk work is done until its latency (the simulation steps
    on while the work runs, its gate opened from simulated time past the input: at --speed max the
    simulation could not pass a loop still counted at its tick), and its result goes out then; on
    the wall clock the work's result goes out as soon as it is done (no latency added)."""
    clock, stop = SimClock(0.0, speed=float("inf")), threading.Event()
    log: list[tuple] = []
    gates: dict[float, threading.Event] = {}
    thread = threading.Thread(target=bulk_loop, args=(clock, stop, 0.2, gates, log), daemon=True)
    thread.start()
    while clock.slowest() is None:
        time.sleep(0.01)

    def opened_past_input(_t_s: float) -> None:  # the simulation got 0.1 s past an input
        for taken_s, gate in list(gates.items()):
            if clock.now_s() >= taken_s + 0.1:
                gate.set()

    simulation = Simulation(clock, end_s=2.5, max_lag_s=0.0)
    clock.on_progress = lambda t_s: (opened_past_input(t_s), simulation._notify())
    try:
        while simulation.thread.is_alive():
            opened_past_input(0.0)
            simulation.thread.join(0.01)
    finally:
        stop.set()
        simulation.close()
        thread.join(6.0)
    taken = [(t, r) for what, t, r in log if what == "cameras"][:2]
    sent = [t for what, t, _ in log if what == "sent"][:2]
    assert [r for _, r in taken] == [(True, 10), (True, 20)]  # the simulation went past each input
    assert [t for t, _ in taken] == pytest.approx([1.0, 2.0], abs=PERIOD_S + 1e-9)  # (woken on a tick)
    assert np.subtract(sent, [t for t, _ in taken]) == pytest.approx([0.2, 0.2], abs=PERIOD_S + 1e-9)

    wall_log: list[tuple] = []

    class Open(dict):  # every gate open: the work ends at once
        def setdefault(self, _key: float, _default: object = None) -> threading.Event:
            gate = threading.Event()
            gate.set()
            return gate

    wall_stop = threading.Event()
    wall = threading.Thread(target=bulk_loop, args=(Clock(), wall_stop, 3.0, Open(), wall_log), daemon=True)
    started = time.monotonic()
    wall.start()  # its first tick a second on
    while not any(what == "sent" for what, _, _ in wall_log) and time.monotonic() - started < 6.0:
        time.sleep(0.01)
    sent_after_s = time.monotonic() - started
    wall_stop.set()
    wall.join(6.0)
    assert [r for what, _, r in wall_log if what == "cameras"][:1] == [
        (True, pytest.approx(10 * wall_log[0][1], abs=1))
    ]
    assert sent_after_s < 3.0  # its tick at 1 s and the work's moment, not its 3 s of latency besides
