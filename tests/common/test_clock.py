"""Simulated time (common.clock): the clock the stations follow, the loops on it, the emulated
links on it, and what the simulation waits for. Real threads and real Zenoh sessions; a thread
stands for the simulation and ticks the clock."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest

from abyss.common import clock as clock_module
from abyss.common import keys
from abyss.common.bus import open_session, zenoh_config
from abyss.common.clock import Holdback, ProgressReport, SimClock
from abyss.common.config import load
from abyss.common.errors import ConfigError
from abyss.common.linkprofile import profile
from abyss.common.lockstep import LockstepClock
from abyss.common.ports import free_port
from abyss.common.rate import Rate
from abyss.linkemu.runner import LinkRunner

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
    monkeypatch.setattr("abyss.common.clock.GUARD_WALL_S", 60.0)
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


def test_a_laggard_whose_progress_stands_still_is_let_go_until_it_reports_past_it(  # type: ignore[no-untyped-def]
    sessions, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A station that keeps saying the same progress (its loop waits for a tick past the one the
    simulation holds at), or the simulation's own loops standing still, stall nothing for good."""
    monkeypatch.setattr(clock_module, "STUCK_WALL_S", 0.5)
    simulation, station = sessions
    own = SimClock(PERIOD_S)
    holdback = Holdback(simulation, "sys", ["onboard"], max_lag_s=0.1, reject=lambda key, reason: None)
    onboard_clock = SimClock(PERIOD_S)
    report = ProgressReport(station, "sys", "onboard", onboard_clock)  # it repeats: never silent
    stop = threading.Event()
    try:
        onboard_clock.done("control", 1.0)
        own.done("cameras", 3.0)
        wall0 = time.monotonic()
        holdback.hold(1.5, stop, own)  # onboard stands at 1.0 < 1.5 - 0.1
        assert 0.4 <= time.monotonic() - wall0 < 3.0 and holdback.let_go == {"onboard": 1.0}
        time.sleep(2 * ProgressReport.REPEAT_WALL_S)  # its repeats of 1.0 do not bring it back
        assert "onboard" in holdback.let_go
        onboard_clock.done("control", 1.6)  # past where it stood: waited for again
        deadline = time.monotonic() + 5.0
        while "onboard" in holdback.let_go and time.monotonic() < deadline:
            time.sleep(0.05)
        assert "onboard" not in holdback.let_go
        holdback.hold(1.6, stop, own)  # onboard at 1.6, the cameras at 3.0: no wait
        holdback.hold(3.5, stop, own)  # onboard stands at 1.6 again, then the cameras at 3.0
        assert holdback.let_go == {"onboard": 1.6, "simulation": 3.0}
        own.done("cameras", 4.0)
        onboard_clock.done("control", 4.0)
        deadline = time.monotonic() + 5.0
        while holdback.let_go and time.monotonic() < deadline:
            holdback.hold(3.9, stop, own)  # looks at the own loops again
            time.sleep(0.05)
        assert holdback.let_go == {}
    finally:
        stop.set()
        report.close()
        holdback.close()


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
