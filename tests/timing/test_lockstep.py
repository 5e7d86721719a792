"""Lockstep's holds and lease (timing.lockstep): the simulation under `abyss up` runs only the
periods the testbed leases it and holds before the first past the lease; a lease is no hold's
release; and the supervisor's end of a run stopped when done (launch.supervise.LockstepEnd):
leased on by shore's statuses, ended a lease past the first that says done. Real Zenoh sessions
where the lease travels; the supervisor's decisions on a stand-in lease."""

from __future__ import annotations

import math
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator

import pytest

from abyss.bus.session import open_session, zenoh_config
from abyss.common.ports import free_port
from abyss.config import load
from abyss.interface.messages import LockstepReport, MissionStatus
from abyss.launch import station as runtime
from abyss.launch.supervise import LEASE_S, LockstepEnd
from abyss.timing import lockstep as lockstep_module
from abyss.timing.lockstep import HOLDS, PHASE_LEASE, TESTBED, Lockstep, LockstepClock, hold_period
from abyss.timing.lockstep_testbed import Lease

pytestmark = pytest.mark.timeout(30)
PERIOD_S = 0.05


@pytest.fixture
def endpoint() -> str:
    return f"tcp/127.0.0.1:{free_port()}"


@pytest.fixture
def sessions(endpoint: str) -> Iterator[tuple[object, object]]:
    testbed = open_session(zenoh_config([endpoint], mode="router"), "testbed")
    simulation = open_session(zenoh_config([], [endpoint], mode="peer"), "simulation")
    yield testbed, simulation
    simulation.close()
    testbed.close()


def _lockstep(
    session: object, station: str = "simulation", **kwargs: object
) -> tuple[Lockstep, threading.Event]:
    stop = threading.Event()
    lockstep = Lockstep(
        session,  # type: ignore[arg-type]
        "sys",
        station,
        LockstepClock(),
        lambda _t_s: Counter(),
        Counter,
        dict,
        (),
        stop,
        lambda key, reason: None,
        period_s=PERIOD_S,
        **kwargs,  # type: ignore[arg-type]
    )
    return lockstep, stop


def _soon(what: Callable[[], bool], timeout_s: float = 5.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while not what():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.01)
    return True


def test_a_hold_is_the_first_period_at_or_after_its_time() -> None:
    assert hold_period(1.0, (1.0,), PERIOD_S) and hold_period(1.05, (1.03,), PERIOD_S)
    assert not hold_period(1.0, (1.03,), PERIOD_S) and not hold_period(1.1, (1.03,), PERIOD_S)
    assert hold_period(0.1 + 0.2, (0.3,), PERIOD_S)  # sums of periods in floats


def test_the_simulation_is_leased_under_abyss_up_alone(sessions, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    assert lockstep_module.SUPERVISOR_ENV == runtime.SUPERVISOR_ENV  # the name abyss up sets
    _, session = sessions
    monkeypatch.delenv(runtime.SUPERVISOR_ENV, raising=False)
    alone, stop = _lockstep(session)
    assert not alone.leased and not alone.hold_at(1e6)  # no supervisor, no lease: it runs on
    stop.set()
    alone.close()
    monkeypatch.setenv(runtime.SUPERVISOR_ENV, "1")
    for station, leased in (("simulation", True), ("onboard", False)):  # the master alone
        lockstep, stop = _lockstep(session, station)
        assert lockstep.leased == leased
        stop.set()
        lockstep.close()


def test_a_leased_simulation_holds_before_the_first_period_past_its_lease(sessions) -> None:  # type: ignore[no-untyped-def]
    testbed, session = sessions
    flushed: list[int] = []
    lockstep, stop = _lockstep(session, leased=True, holds_s=(3.0,), before_hold=lambda: flushed.append(1))
    lease = Lease(testbed, "sys", lambda key, reason: None)
    try:
        assert lockstep.hold_at(0.0)  # nothing leased yet: not even the first period
        lease.grant(1.0)
        assert _soon(lambda: not lockstep.hold_at(0.0))
        assert not lockstep.hold_at(1.0 - PERIOD_S) and lockstep.hold_at(1.0)  # the periods before it
        assert lockstep.reported(TESTBED, "release")[0] == -math.inf  # a lease is no hold's release
        went_on = threading.Event()
        threading.Thread(target=lambda: lockstep.hold(1.0, lambda: 0) and went_on.set(), daemon=True).start()
        assert _soon(lambda: lease.held_at(1.0))  # the testbed sees it held there
        assert not lease.held_at(1.05) and not went_on.wait(0.3)
        lease.grant(0.5)  # a shorter lease changes nothing
        assert not went_on.wait(0.2)
        lease.grant(2.0)
        assert went_on.wait(5.0)
        assert not flushed  # not a hold: its recording is not flushed, no epoch begins
        lease.grant(5.0)
        assert _soon(lambda: lockstep.leased_to(4.9))
        assert lockstep.hold_at(3.0) and not lockstep.hold_at(3.05)  # a hold still holds, leased or not
    finally:
        stop.set()
        lockstep.close()
        lease.close()


class _Lease:
    """The supervisor's lease, standing in: what it granted, where the simulation is held, which
    stations delivered which period."""

    def __init__(self) -> None:
        self.until_s = 0.0
        self.held_s = -math.inf
        self.delivered_s: dict[str, float] = {}
        self.added_s: tuple[float, ...] = ()

    def added_holds_s(self) -> tuple[float, ...]:
        return self.added_s

    def grant(self, until_s: float) -> None:
        self.until_s = max(self.until_s, until_s)

    def held_at(self, t_s: float) -> bool:
        return self.held_s >= t_s - 1e-6

    def delivered_at(self, station: str, t_s: float) -> bool:
        return self.delivered_s.get(station, -math.inf) >= t_s - 1e-6


def _status(done: bool) -> MissionStatus:
    return MissionStatus(
        mode="reached" if done else "moving",
        waypoint_index=1,
        waypoints_total=1,
        position_error_m=0.0,
        heading_error_rad=0.0,
        arm_mode="idle",
        ee_position_error_m=0.0,
        ee_orientation_error_rad=0.0,
        failsafe="",
        failsafe_events=0,
        done=done,
    )


def test_the_run_ends_a_lease_past_shores_first_status_that_says_done() -> None:
    lease = _Lease()
    ending = LockstepEnd(lease, load(None, ["time.mode=lockstep"]))  # type: ignore[arg-type]
    ending.on_status(2.0, _status(False))
    assert lease.until_s == 2.0 + LEASE_S and ending.end_s is None
    ending.on_status(2.25, _status(True))
    assert ending.done_s == 2.25 and ending.end_s == 2.25 + LEASE_S and lease.until_s == 2.25 + LEASE_S
    ending.on_status(2.5, _status(True))  # heard late or not, the end stays where the first put it
    assert ending.done_s == 2.25 and lease.until_s == 2.25 + LEASE_S
    assert not ending.reached()
    lease.held_s = 2.25 + LEASE_S
    assert not ending.reached()  # held, but a station has not delivered ahead into the period yet
    lease.delivered_s = dict.fromkeys(("onboard", "vessel", "onshore"), 2.25 + LEASE_S)
    assert ending.reached()
    ending.again()  # done on shore, not in the truth: on a lease more, judged there again
    assert ending.end_s == 2.25 + 2 * LEASE_S and lease.until_s == ending.end_s and not ending.reached()
    lease.held_s, lease.added_s = ending.end_s, (ending.end_s,)  # a hold the runner added, there
    assert ending.reached()  # no station delivers ahead into a hold's period


def test_a_run_kept_running_is_leased_to_no_end() -> None:
    lease = _Lease()
    ending = LockstepEnd(lease, load(None, ["time.mode=lockstep"]))  # type: ignore[arg-type]
    ending.keep_running()
    ending.on_status(2.0, _status(True))
    assert lease.until_s >= 1e9 and ending.end_s is None and not ending.reached()


def test_a_hold_added_during_the_run_reaches_every_station_before_the_runner_leases_past_it(
    sessions, endpoint
) -> None:  # type: ignore[no-untyped-def]
    """The scenario runner's hold for an event timed on a phase (time.phase_holds): the simulation
    runs only the periods of the runner's lease, however far the supervisor's goes; each station
    takes the added holds (one started later too, from the repeats) and reports how many it has."""
    testbed, session = sessions
    apart = open_session(
        zenoh_config([f"tcp/127.0.0.1:{free_port()}"], [endpoint], mode="peer"), "supervisor"
    )
    supervisor = Lease(apart, "sys", lambda key, reason: None)  # abyss up's, in a process of its own
    runner = Lease(testbed, "sys", lambda key, reason: None, key=PHASE_LEASE)
    simulation, stop = _lockstep(session, leased=True, phase_leased=True)
    onboard, onboard_stop = _lockstep(session, "onboard", listens=(TESTBED,))
    later: list[Lockstep] = []
    stops = [stop, onboard_stop]
    try:
        supervisor.grant(10.0)
        assert _soon(lambda: simulation.leased_to(0.0) is False and simulation._lease_s == 10.0)
        assert simulation.hold_at(0.0)  # the runner leased nothing yet
        runner.grant(1.0)
        assert _soon(lambda: not simulation.hold_at(0.95)) and simulation.hold_at(1.0)
        assert simulation.reported(TESTBED, "release")[0] == -math.inf  # a lease, no hold's release
        runner.add_hold(1.52)
        assert _soon(lambda: simulation.hold_period(1.55) and onboard.hold_period(1.55))
        assert not onboard.hold_period(1.5) and not onboard.hold_period(
            1.6
        )  # the first period at or after it
        assert _soon(lambda: runner.have_holds(("simulation", "onboard")))
        assert not runner.have_holds(("simulation", "onboard", "vessel"))  # one not there has none
        vessel, vessel_stop = _lockstep(session, "vessel", listens=(TESTBED,), boot=1)
        later.append(vessel)
        stops.append(vessel_stop)
        assert _soon(lambda: vessel.hold_period(1.55) and runner.have_holds(("simulation", "vessel")))
        runner.add_hold(0.5)  # not in time order: each station counts them all
        assert _soon(lambda: runner.have_holds(("simulation", "onboard", "vessel")))
        assert onboard.hold_period(0.5) and onboard.hold_period(1.55)
        assert _soon(lambda: supervisor.added_holds_s() == (1.52, 0.5))  # the supervisor hears them too
        runner.grant(3.0)
        assert _soon(lambda: not simulation.hold_at(2.95)) and simulation.hold_at(1.55)  # the hold holds
    finally:
        for done in stops:
            done.set()
        for each in (simulation, onboard, *later):
            each.close()
        runner.close()
        supervisor.close()
        apart.close()


def test_holds_added_in_a_burst_are_counted_to_the_last_and_an_older_report_does_not_undo_it(
    sessions,
) -> None:  # type: ignore[no-untyped-def]
    """Two phases reported in one telemetry add two holds at once: each station's count of them
    is told in the order it grew (a thread per addition told an older count last, the runner
    never leased past the first hold, and the run stood still: CI, tether-outage), and the
    testbed keeps a station's latest report, not the last to arrive."""
    testbed, session = sessions
    runner = Lease(testbed, "sys", lambda key, reason: None, key=PHASE_LEASE)
    onboard, stop = _lockstep(session, "onboard", listens=(TESTBED,))
    try:
        for i in range(12):
            runner.add_hold(1.0 + i * PERIOD_S)
        assert _soon(lambda: runner.have_holds(("onboard",)))
        time.sleep(3 * lockstep_module.REPEAT_WALL_S)  # the repeats tell the count again meanwhile
        assert runner.have_holds(("onboard",)) and onboard._last[HOLDS][0] == 12.0
        latest = runner.reported("onboard", HOLDS)
        assert latest is not None
        runner._take("onboard", LockstepReport(sim_time_s=11.0, phase=HOLDS, boot=latest.boot))
        assert runner.have_holds(("onboard",))  # an older count, arriving late, is not taken
        runner._take("onboard", LockstepReport(sim_time_s=0.0, phase=HOLDS, boot=latest.boot + 1))
        assert not runner.have_holds(("onboard",))  # a restarted station's is, and it has none yet
    finally:
        stop.set()
        onboard.close()
        runner.close()
