"""`abyss up`'s supervision: waits for every station to come up, then watches the run until the
mission is done, the duration has passed, a station dies (or is restarted) or the user
interrupts; says how the mission goes every few seconds.

In lockstep the mission's end is decided on the simulated clock (`LockstepEnd`): the simulation
runs the periods the supervisor leases it (timing.lockstep_testbed, Lease), LEASE_S past shore's latest
mission status; the first status that says done, stamped with its period T, ends the lease at
T + LEASE_S, where the simulation holds with every station done with the period before. The
supervisor stops the run there, so every station ran the same periods and the records end on
the same row, however late it heard the status."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import zenoh

from abyss.common.errors import BadMessage
from abyss.config import Config
from abyss.interface import keys
from abyss.interface.messages import MissionStatus, ReplayStart, decode, encode
from abyss.launch.observe import Heard, Outage
from abyss.launch.start import Replayed, Starter, Station, ros2_line
from abyss.launch.verdict import exit_text
from abyss.timing.clock import SimClock
from abyss.timing.lockstep import ENDLESS_S, TICK_TOLERANCE_S, hold_period
from abyss.timing.lockstep_testbed import Lease

STARTUP_TIMEOUT_S = 60.0
EXTERNAL_TIMEOUT_S = 120.0  # more for a station a person or another tool starts
REPLAY_DELAY_S = 1.0  # from every station up to the replayed stations' first message
REPORT_PERIOD_S = 5.0  # how often the watch says how the mission goes
# lockstep: how far past shore's latest mission status the simulation may run, and so past the
# first that says done the run ends [simulated s] (a lease of 4 statuses: the simulation waits
# for the supervisor only when it hears them a simulated second late)
LEASE_S = 1.0
log = logging.getLogger(__name__)


@dataclass
class LockstepEnd:
    """Lockstep: the end of a run that stops when its mission is done, on the simulated clock
    (see the module). `on_status` takes each of shore's statuses with its stamp (its period) and
    leases on; `reached` is true once the simulation holds at `end_s` and every other station has
    delivered that period's messages (a station done with the period before delivers the next
    one's at once: after that nothing moves until the stop). There the supervisor judges the
    mission on the simulation's truth too: done, the run stops; not, `again` leases LEASE_S more."""

    lease: Lease
    config: Config
    stop_when_done: bool = True  # False: --keep-running, an endless lease
    done_s: float | None = None  # the period of shore's first status that says done
    end_s: float | None = None  # where the simulation holds, the mission done on shore
    statuses: zenoh.Subscriber | None = None  # shore's, for `on_status` (closed with the session)

    def on_status(self, stamp_s: float, status: MissionStatus) -> None:
        if not self.stop_when_done or self.end_s is not None:
            return
        if status.done:
            self.done_s, self.end_s = stamp_s, stamp_s + LEASE_S
        self.lease.grant(stamp_s + LEASE_S)

    def keep_running(self) -> None:
        self.stop_when_done = False
        self.lease.grant(ENDLESS_S)

    def reached(self) -> bool:
        end_s = self.end_s
        if not self.stop_when_done or end_s is None or not self.lease.held_at(end_s):
            return False
        period_s, time_ = self.config.simulation.control_period_s, self.config.time
        if hold_period(end_s, (*time_.holds_s, *self.lease.added_holds_s()), period_s) or (
            time_.end_s and end_s >= time_.end_s - TICK_TOLERANCE_S
        ):
            return True  # no station delivers ahead into a hold's period, nor past the run's end
        return all(self.lease.delivered_at(s, end_s) for s in keys.STATIONS if s != "simulation")

    def again(self) -> None:
        """Done on shore, not in the simulation's truth: on for LEASE_S, and judged again there."""
        assert self.end_s is not None
        self.end_s += LEASE_S
        self.lease.grant(self.end_s)


@dataclass
class Supervisor:
    """The stations of one run, and what became of them: deaths, restarts, the mission done."""

    config: Config
    starter: Starter
    heard: Heard
    echo: Callable[[str], None]
    interrupted: threading.Event
    change_state: Callable[..., None]
    external: tuple[str, ...] = ()
    restart: bool = False  # a station that dies is started again instead of failing the run
    sim_clock: SimClock | None = None  # with simulated time, the run's time is the simulation's
    replayed: Replayed | None = None
    session: zenoh.Session | None = None  # the supervisor's, while it runs
    stations: dict[str, Station] = field(default_factory=dict)
    restarts: list[Outage] = field(default_factory=list)
    up_s: float | None = None  # when all stations were first up (monotonic)
    mission_done_s: float | None = None  # since all stations were up (the run's time)
    mission_done_wall_s: float | None = None
    watch_from: tuple[float, float] | None = None  # (the run's time, monotonic) when watched from
    replay_start: ReplayStart | None = None
    never_came: tuple[str, ...] = ()  # external stations still away when the duration passed
    ending: LockstepEnd | None = None  # lockstep: the simulation's lease and the run's end

    # -- deaths and restarts -------------------------------------------------------------------
    def check_deaths(self) -> list[Station]:
        dead = []
        for station in self.stations.values():
            code = station.process.poll()
            if code is not None and station.died is None:
                station.died = code
                dead.append(station)
        return dead

    def report_death(self, station: Station) -> None:
        tail = station.log_path.read_text(errors="replace").splitlines()[-15:]
        self.echo(
            f"abyss: station {station.name} died with exit code {exit_text(station.died)}; "
            f"log {station.log_path}:"
        )
        for line in tail:
            self.echo(f"    {line}")

    def restart_station(self, station: Station) -> None:
        restarted = self.starter.start(station.name, station.restarts + 1)
        restarted.restarts = station.restarts + 1
        self.stations[station.name] = restarted
        self.change_state(station.name, restarts=restarted.restarts)
        now_s = time.monotonic()
        with self.heard.lock:
            outage = Outage(
                station.name, station.died, now_s - (self.up_s or now_s), now_s, self.heard.truth_m_world
            )
            self.restarts.append(outage)
            self.heard.down[station.name] = outage
        self.echo(
            f"abyss:   {station.name} restarted (pid {restarted.process.pid}, restart {restarted.restarts})"
        )

    # -- start-up ------------------------------------------------------------------------------
    def start_all(self) -> None:
        """Every station but the external ones, for which it says how to start them; in lockstep
        the simulation's lease first (it runs no period before it hears one)."""
        system = self.config.system
        if self.config.time.mode == "lockstep" and self.session is not None:
            lease = Lease(
                self.session, system, lambda key, reason: log.warning("%s: %s", key, reason), LEASE_S
            )
            self.ending = LockstepEnd(lease, self.config)
            self.ending.statuses = self.session.declare_subscriber(keys.mission_key(system), self._on_status)
        for name in keys.STATIONS:
            if name in self.external:
                self.change_state(name, external=True)
                self.echo(
                    f"abyss: waiting for external station {name}: start it with `abyss station "
                    f"{name} --system {system} --connect {self.starter.endpoint}`"
                )
            else:
                self.stations[name] = self.starter.start(name)
            if name == self.config.ros2.station:
                self.echo(ros2_line(self.config.ros2))

    def wait_until_up(self, t0: float, duration_s: float | None = None) -> str:
        """'' once every station is alive (or on an interrupt, or once `duration_s` [s, wall] has
        passed with every station up but an external one: `never_came` names it, and the run
        ends incomplete), else why not."""
        shown: set[str] = set()
        timeout_s = STARTUP_TIMEOUT_S + (EXTERNAL_TIMEOUT_S if self.external else 0.0)
        while time.monotonic() - t0 < timeout_s:
            with self.heard.lock:
                alive = set(self.heard.alive)
            for name in sorted(alive - shown):
                pid = self.stations[name].process.pid if name in self.stations else "external"
                self.echo(f"abyss:   {name} up (pid {pid}, {time.monotonic() - t0:.1f} s)")
            shown |= alive
            if alive >= set(keys.STATIONS):
                return ""
            away = tuple(name for name in keys.STATIONS if name not in alive)
            # once the stations it started are up (one stopped while it boots dies of the SIGINT)
            if (
                set(away) <= set(self.external)
                and duration_s is not None
                and time.monotonic() - t0 >= duration_s
            ):
                self.never_came = away
                self.echo(
                    f"abyss: external station {', '.join(away)} never came: nothing joined as "
                    f"{'it' if len(away) == 1 else 'them'} at {self.starter.endpoint} within the run's "
                    f"--duration of {duration_s:g} s; stopping"
                )
                return ""
            for station in self.check_deaths():
                self.report_death(station)
                return f"{station.name} died during start-up"
            if self.ending is not None:
                self.ending.lease.tell()
            if self.interrupted.wait(0.05):
                return ""  # the verdict says interrupted
        missing = sorted(set(keys.STATIONS) - shown)
        return f"not up after {timeout_s:g} s: {', '.join(missing)}"

    # -- the watch -----------------------------------------------------------------------------
    def now_s(self) -> float:
        """The run's time: the wall clock's, or the simulation's with simulated time."""
        return self.sim_clock.now_s() if self.sim_clock is not None else time.monotonic()

    def watch(self, duration_s: float | None, keep_running: bool) -> str:
        """'' when the run ends as it should (the mission done, the duration passed, an
        interrupt), else the failure: a station died and is not restarted."""
        # simulated time counts from the simulation's start, which waits for every station
        t0, wall0 = 0.0 if self.sim_clock is not None else self.now_s(), time.monotonic()
        self.watch_from = (t0, wall0)
        last_report = next_start_s = wall0
        self._announce_replay()
        ending = self.ending
        if ending is not None and keep_running:
            ending.keep_running()
        while True:
            if ending is not None:
                ending.lease.tell()
            if self.replay_start is not None and time.monotonic() >= next_start_s:
                next_start_s = time.monotonic() + 1.0  # again each second, for a replayer that starts late
                self._put(keys.replay_key(self.config.system), self.replay_start)
            for station in self.check_deaths():
                self.report_death(station)
                if not self.restart:
                    return f"{station.name} died"
                self.restart_station(station)
            mission = self.heard.mission
            elapsed = self.now_s() - t0
            # done when shore says so and the simulation's truth agrees (lockstep: at the period
            # its lease ends, LockstepEnd)
            done = mission is not None and mission.done and self.heard.interventions_true(self.config)
            if ending is not None and ending.stop_when_done:
                # and what the simulation observed up to there has come (the panel's truth that
                # judges the mission and goes in panel.csv: the last one, not an older one)
                last_period_s = (ending.end_s or 0.0) - self.config.simulation.control_period_s
                reached = ending.reached() and self.heard.truth_s >= last_period_s - TICK_TOLERANCE_S
                done = reached and self.heard.interventions_true(self.config)
                if reached and not done:
                    ending.again()
            if done and self.mission_done_s is None:
                self._mission_done(ending.done_s if ending and ending.done_s is not None else elapsed, wall0)
            if (done and not keep_running) or (duration_s is not None and elapsed >= duration_s):
                return ""
            if time.monotonic() - last_report >= REPORT_PERIOD_S:
                last_report = time.monotonic()
                self.echo(
                    f"abyss: t={elapsed:5.0f} s{self.speed_note(wall0)}  mission: {progress(mission, done)}"
                )
            if self.interrupted.wait(0.1):
                self.echo("abyss: interrupted; stopping the stations")
                return ""  # the verdict says interrupted unless the mission was already done

    def _announce_replay(self) -> None:
        if self.replayed is None:
            return
        self.replay_start = ReplayStart(time.time() + REPLAY_DELAY_S)
        self.echo(
            f"abyss: replaying {', '.join(self.replayed.stations)} of {self.replayed.run_dir} "
            f"from t={REPLAY_DELAY_S:g} s (speed {self.replayed.speed:g})"
        )

    def _on_status(self, sample: zenoh.Sample) -> None:
        """Lockstep: shore's mission status with its period, to lease the simulation on."""
        try:
            received = decode(str(sample.key_expr), sample.payload.to_bytes(), MissionStatus)
        except BadMessage:
            return
        if self.ending is not None:
            self.ending.on_status(received.stamp_s, received.message)

    def _put(self, key: str, message: ReplayStart) -> None:
        if self.session is not None:
            self.session.put(key, encode(message, 0, time.time()))

    def _mission_done(self, elapsed_s: float, wall0: float) -> None:
        self.mission_done_s = elapsed_s
        self.mission_done_wall_s = time.monotonic() - wall0
        self.change_state(mission_done=True)
        self.echo(
            f"abyss: mission complete at t={elapsed_s:.1f} s"
            + (
                f" simulated, {self.mission_done_wall_s:.1f} s of wall time"
                if self.sim_clock is not None
                else ""
            )
        )

    def speed_note(self, wall0: float) -> str:
        """With simulated time: the speed so far, e.g. ` (x3.8)`."""
        if self.sim_clock is None or self.watch_from is None or time.monotonic() <= wall0:
            return ""
        return f" (x{(self.now_s() - self.watch_from[0]) / (time.monotonic() - wall0):.1f})"


def progress(mission: MissionStatus | None, done: bool) -> str:
    """How the mission goes, as the watch says it every few seconds."""
    if not mission:
        return "no telemetry on shore yet"
    return (
        f"{mission.mode}, waypoint {mission.waypoint_index}/"
        f"{mission.waypoints_total}, error {mission.position_error_m:.2f} m; arm "
        f"{mission.arm_mode}, error {mission.ee_position_error_m * 1e3:.0f} mm"
        + (
            f"; intervention {mission.interventions_done}/{mission.interventions_total} "
            f"{mission.intervention_target} {mission.intervention_phase}"
            if mission.interventions_total
            else ""
        )
        + (f" ({mission.intervention_reason})" if mission.intervention_reason else "")
        + (f"; FAILSAFE: {mission.failsafe}" if mission.failsafe else "")
        + ("; done on shore, not in the simulation's truth" if mission.done and not done else "")
    )
