"""`abyss up`'s supervision: waits for every station to come up, then watches the run until the
mission is done, the duration has passed, a station dies (or is restarted) or the user
interrupts; says how the mission goes every few seconds."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import zenoh

from abyss.common import keys
from abyss.common.clock import SimClock
from abyss.common.config import Config
from abyss.common.messages import MissionStatus, ReplayStart, encode
from abyss.launch.observe import Heard, Outage
from abyss.launch.start import Replayed, Starter, Station, ros2_line
from abyss.launch.summary import exit_text

STARTUP_TIMEOUT_S = 60.0
EXTERNAL_TIMEOUT_S = 120.0  # more for a station a person or another tool starts
REPLAY_DELAY_S = 1.0  # from every station up to the replayed stations' first message
REPORT_PERIOD_S = 5.0  # how often the watch says how the mission goes


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
        """Every station but the external ones, for which it says how to start them."""
        system = self.config.system
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
        while True:
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
            # done when shore says so and the simulation's truth agrees
            done = mission is not None and mission.done and self.heard.interventions_true(self.config.mission)
            if done and self.mission_done_s is None:
                self._mission_done(elapsed, wall0)
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
