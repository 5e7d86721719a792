"""`abyss up`: the four stations as four OS processes on this machine."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import zenoh

from abyss.common import keys
from abyss.common.bus import open_session, zenoh_config
from abyss.common.clock import SimClock
from abyss.common.clock import follow as clock_follow
from abyss.common.config import Config
from abyss.common.config_stations import OnshoreConfig
from abyss.common.config_system import Ros2Config
from abyss.common.errors import AbyssError, BadMessage, ConfigError
from abyss.common.messages import (
    MissionStatus,
    NavState,
    PanelState,
    ReplayStart,
    SimulationStatus,
    Telemetry,
    decode,
    encode,
)
from abyss.common.runfiles import CARRIED_OVER, EVENTS_FILE, read_json_list
from abyss.launch.cpu import CpuCaps
from abyss.launch.record import ControlRecorder
from abyss.launch.state import RunState
from abyss.launch.summary import (
    NavError,
    control_summary,
    exit_code,
    exit_text,
    interventions_summary,
    read_json,
    render_summary,
    verdict_of,
)
from abyss.recording.store import RECORD_DIR, TESTBED, Recorder
from abyss.stations.runtime import BOOT_ENV, NATIVE_POOLS, SUPERVISOR_ENV, free_port, station_recorder

DEFAULT_PORT = 7447
STARTUP_TIMEOUT_S = 60.0
EXTERNAL_TIMEOUT_S = 120.0  # more for a station a person or another tool starts
CONFIG_FILE = "config.json"  # what the stations (and a replay of the run) are given
SIMULATION_STATE_FILE = "simulation-state.npy"  # a restarted simulation resumes from it
REPLAY_DELAY_S = 1.0  # from every station up to the replayed stations' first message
STOP_TIMEOUT_S = 10.0  # twice a station's stop bound (stations.runtime): past it, a defect
# a restarted station is back when its session is up and, for these, once its output is seen
# again (onboard's telemetry, the simulation's truth): a session comes up before the station runs
HEARD_FROM: dict[str, type] = {"onboard": Telemetry, "simulation": NavState}


@dataclass
class Outage:
    """A station that died and was restarted: until it is back (its session up and, where the
    supervisor sees its output, that output again), how far the vehicle strays."""

    station: str
    exit_code: int | None
    t_s: float  # since all stations were up
    died_s: float  # monotonic
    from_m_world: np.ndarray | None  # the vehicle's position when the station died
    alive: bool = False  # its session is back
    down_s: float | None = None  # until it was back; None while it is not
    drift_m: float = 0.0

    def summary(self) -> dict[str, Any]:
        return {
            "station": self.station,
            "exit_code": self.exit_code,
            "t_s": round(self.t_s, 3),
            "down_s": self.down_s,
            "drift_m": round(self.drift_m, 4),
        }


@dataclass
class Station:
    name: str
    process: subprocess.Popen[bytes]
    log_path: Path
    status_path: Path
    restarts: int = 0
    died: int | None = None  # exit code if it ended before it was asked to stop


class Placement(Protocol):
    """Where the stations run and how they reach each other and the supervisor."""

    def prefix(self, station: str) -> list[str]: ...
    def args(self, station: str, endpoint: str) -> list[str]: ...


class Local:
    """Every station a process of this host on loopback, a peer under the supervisor's router."""

    def prefix(self, station: str) -> list[str]:
        return []

    def args(self, station: str, endpoint: str) -> list[str]:
        return ["--listen", "tcp/127.0.0.1:0", "--connect", endpoint, "--zenoh-mode", "peer"]


def port_free(port: int) -> bool:
    with socket.socket() as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


@dataclass(frozen=True)
class Replayed:
    """Stations played back from a recorded run instead of run (`abyss replay`)."""

    run_dir: Path
    stations: tuple[str, ...]
    speed: float = 1.0

    def args(self, station: str) -> list[str]:
        return ["--replay", str(self.run_dir), "--speed", str(self.speed)] if station in self.stations else []


# lockstep: one thread in every native pool whatever the user's environment says (a station's own
# default otherwise, single_threaded_native_pools), the order of floating-point sums fixed
SINGLE_THREADED = dict.fromkeys(NATIVE_POOLS, "1")


class Up:
    """Start, watch and stop one whole system; write its summary."""

    def __init__(
        self,
        config: Config,
        out_dir: Path,
        port: int | None = None,
        echo: Any = None,
        external: Sequence[str] = (),
        restart: bool = False,
        placement: Placement | None = None,
        replayed: Replayed | None = None,
    ) -> None:
        self.config = config
        self.replayed = replayed
        self.replay_start: ReplayStart | None = None
        self.session: zenoh.Session | None = None  # the supervisor's, while it runs
        self.placement = placement or Local()
        self.external = tuple(keys.check_station(name) for name in external)  # started by the user
        if config.ros2.station in self.external:
            raise ConfigError(
                "--ros2",
                f"{config.ros2.station} is --external too: the gateway stands for a "
                "station that abyss up starts",
            )
        self.restart = restart  # a station that dies is started again instead of failing the run
        uncappable = sorted(set(config.cpu.capped()) & set(self.external))
        if uncappable:
            raise ConfigError(
                "--cpu", f"{uncappable[0]} is --external: abyss up does not start it, so cannot cap its CPU"
            )
        self.time = config.time
        if self.time.simulated:
            for refused, what in (("--external", self.external), ("--replay", replayed)):
                if what:
                    raise ConfigError(
                        refused,
                        "a real component or a replay runs on the wall clock, which "
                        "--time sim cannot speed up; use --time real with it",
                    )
            if self.time.mode == "lockstep" and restart:
                raise ConfigError(
                    "--restart",
                    "a station restarted mid-period leaves lockstep's counted "
                    "periods behind: use --time sim or real with it",
                )
            if config.cpu.capped():
                raise ConfigError(
                    "--cpu",
                    "a CPU cap is a share of wall time, and with --time sim the "
                    "simulation waits for a station that needs more: use --time real with it",
                )
        self.cpu = CpuCaps(config.system, config.cpu.capped())  # fails here where no cgroup can be made
        # with simulated time, the run's time is the simulation's (its duration, the mission's)
        self.sim_clock = (
            SimClock(config.simulation.control_period_s, self.time.speed_factor)
            if self.time.simulated
            else None
        )
        self.mission_done_s: float | None = None  # since all stations were up (the run's time)
        self.mission_done_wall_s: float | None = None
        self.watch_from: tuple[float, float] | None = None  # (the run's time, monotonic) when watched from
        self.out_dir = out_dir.resolve()  # the stations run there, whatever the caller's directory
        self.echo = echo or (lambda text: print(text, flush=True))
        if port is None:
            ros2_ports = {e.rpartition(":")[2] for e in config.ros2.listen} if config.ros2.station else set()
            taken = str(DEFAULT_PORT) in ros2_ports  # the gateway's router: rmw_zenohd's port, by default
            port = DEFAULT_PORT if not taken and port_free(DEFAULT_PORT) else free_port()
        elif port == 0:
            port = free_port()
        self.endpoint = f"tcp/127.0.0.1:{port}"
        self.alive: set[str] = set()
        self.alive_seen: set[str] = set()
        self.mission: MissionStatus | None = None
        self.simulation: SimulationStatus | None = None
        self.record: ControlRecorder | None = None
        self.testbed: Recorder | None = None  # the observation keys' recording
        self.stations: dict[str, Station] = {}
        self.restarts: list[Outage] = []
        self._down: dict[str, Outage] = {}  # restarts whose station is not back yet
        self.truth_m_world: np.ndarray | None = None  # the vehicle's position, from the simulation
        self.nav_error = NavError()  # onboard's estimate against it
        self.panel: tuple[PanelState, PanelState] | None = None  # the panel's truth: the first, the latest
        self.up_s: float | None = None  # when all stations were first up (monotonic)
        self.interrupted = threading.Event()
        self.keep_running = False
        self._lock = threading.Lock()
        self.state = RunState(config.system, self.endpoint, os.getpid())
        self._state_lock = threading.Lock()

    # -- zenoh observers -----------------------------------------------------------------
    def _on_alive(self, sample: zenoh.Sample) -> None:
        name = str(sample.key_expr).split("/")[2]
        with self._lock:
            if sample.kind == zenoh.SampleKind.PUT:
                self.alive.add(name)
                self.alive_seen.add(name)
                if name in self._down:  # its session is back; it is up once it is heard from
                    self._down[name].alive = True
                    if name not in HEARD_FROM:
                        self._back(name)
            else:
                self.alive.discard(name)
            self._change_state(name, up=name in self.alive)

    def _on_status(self, sample: zenoh.Sample) -> None:
        """Mission status from shore, simulation status from the simulation, the controllers'
        telemetry from onboard."""
        try:
            message = decode(str(sample.key_expr), sample.payload.to_bytes()).message
        except BadMessage:
            return
        if isinstance(message, NavState):  # the simulation's truth
            with self._lock:
                for down in self._down.values():
                    if down.from_m_world is not None:
                        drift_m = float(np.linalg.norm(message.position_m_world - down.from_m_world))
                        down.drift_m = max(down.drift_m, drift_m)
                self.truth_m_world = message.position_m_world
                self.nav_error.add_truth(message.sim_time_s, message.position_m_world)
        with self._lock:
            for name, kind in HEARD_FROM.items():
                if isinstance(message, kind) and name in self._down and self._down[name].alive:
                    self._back(name)
        if isinstance(message, PanelState):
            self.panel = (self.panel[0] if self.panel else message, message)
            if self.record is not None:
                self.record.add(message)
        if isinstance(message, MissionStatus):
            self.mission = message
        elif isinstance(message, SimulationStatus):
            self.simulation = message
        elif isinstance(message, Telemetry):
            with self._lock:
                self.nav_error.add_estimate(message)
            if self.record is not None:
                self.record.add(message)

    def _put(self, key: str, message: ReplayStart) -> None:
        if self.session is not None:
            self.session.put(key, encode(message, 0, time.time()))

    def _on_observed(self, sample: zenoh.Sample) -> None:
        if self.testbed is not None:
            self.testbed.add("observed", str(sample.key_expr), sample.payload.to_bytes())

    def _change_state(self, station: str | None = None, **changes: Any) -> None:
        """Change the run's state (or one station's in it) and write `state.json` at once, under
        the lock: Zenoh's callbacks change it too."""
        with self._state_lock:
            if station is None:
                self.state = dataclasses.replace(self.state, **changes)
            else:
                self.state = self.state.with_station(station, **changes)
            if self.out_dir.is_dir():
                self.state.write(self.out_dir)

    # -- processes -----------------------------------------------------------------------
    def _start(self, name: str, config_path: Path, boot: int = 0) -> Station:
        log_path = self.out_dir / f"{name}.log"
        status_path = self.out_dir / f"{name}.json"
        # -P: the stations' own directory (the run directory) never shadows abyss's modules
        command = [
            *self.placement.prefix(name),
            sys.executable,
            "-P",
            "-m",
            "abyss.cli",
            "station",
            name,
            "--config",
            str(config_path),
            "--status-file",
            str(status_path),
            *self.placement.args(name, self.endpoint),
            *(self.replayed.args(name) if self.replayed else []),
        ]
        with log_path.open("wb") as log:
            process = subprocess.Popen(
                command,
                stdout=log,
                stderr=subprocess.STDOUT,
                stdin=subprocess.DEVNULL,
                start_new_session=True,
                cwd=self.out_dir,
                env={
                    **os.environ,
                    SUPERVISOR_ENV: str(os.getpid()),
                    BOOT_ENV: str(boot),
                    **(SINGLE_THREADED if self.time.mode == "lockstep" else {}),
                },
            )
        self.cpu.apply(name, process.pid)
        self._change_state(name, pid=process.pid)
        return Station(name, process, log_path, status_path)

    def _back(self, name: str) -> None:
        """A restarted station is up again: how long it was down (the caller holds the lock)."""
        down = self._down.pop(name)
        down.down_s = round(time.monotonic() - down.died_s, 3)

    def _check_deaths(self) -> list[Station]:
        dead = []
        for station in self.stations.values():
            code = station.process.poll()
            if code is not None and station.died is None:
                station.died = code
                dead.append(station)
        return dead

    def _restart(self, station: Station) -> None:
        restarted = self._start(station.name, self.out_dir / CONFIG_FILE, station.restarts + 1)
        restarted.restarts = station.restarts + 1
        self.stations[station.name] = restarted
        self._change_state(station.name, restarts=restarted.restarts)
        now_s = time.monotonic()
        with self._lock:
            outage = Outage(
                station.name, station.died, now_s - (self.up_s or now_s), now_s, self.truth_m_world
            )
            self.restarts.append(outage)
            self._down[station.name] = outage
        self.echo(
            f"abyss:   {station.name} restarted (pid {restarted.process.pid}, restart {restarted.restarts})"
        )

    def _report_death(self, station: Station) -> None:
        tail = station.log_path.read_text(errors="replace").splitlines()[-15:]
        self.echo(
            f"abyss: station {station.name} died with exit code {exit_text(station.died)}; "
            f"log {station.log_path}:"
        )
        for line in tail:
            self.echo(f"    {line}")

    def _stop_all(self) -> str:
        """SIGINT to every station; one that has not stopped in `STOP_TIMEOUT_S` is killed, and
        that is a failure of the run (a station must stop within its bound)."""
        for station in self.stations.values():
            if station.process.poll() is None:
                station.process.send_signal(signal.SIGINT)
        deadline = time.monotonic() + STOP_TIMEOUT_S
        stuck = []
        for station in self.stations.values():
            try:
                station.process.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                self.echo(f"abyss: {station.name} did not stop in {STOP_TIMEOUT_S:g} s; killing it")
                station.process.kill()
                station.process.wait()
                stuck.append(station.name)
        return f"{', '.join(stuck)} did not stop within {STOP_TIMEOUT_S:g} s" if stuck else ""

    # -- the run -------------------------------------------------------------------------
    def run(self, duration_s: float | None, keep_running: bool) -> int:
        self.out_dir.mkdir(parents=True, exist_ok=True)
        onshore = self.config.onshore
        web_port, grpc_port = (
            p if port_free(p) else free_port() for p in (onshore.viewer_web_port, onshore.viewer_grpc_port)
        )
        self.config = dataclasses.replace(
            self.config,
            onshore=dataclasses.replace(
                onshore, record_dir=str(self.out_dir), viewer_web_port=web_port, viewer_grpc_port=grpc_port
            ),
            simulation=dataclasses.replace(
                self.config.simulation, state_file=str(self.out_dir / SIMULATION_STATE_FILE)
            ),
            # lockstep ends on the same period however late the stop comes
            time=dataclasses.replace(self.config.time, end_s=duration_s or 0.0)
            if self.time.mode == "lockstep"
            else self.config.time,
            record=dataclasses.replace(self.config.record, directory=str(self.out_dir / RECORD_DIR)),
        )
        shutil.rmtree(self.out_dir / RECORD_DIR, ignore_errors=True)  # an earlier run's
        for name in (SIMULATION_STATE_FILE, *CARRIED_OVER):  # an earlier run's: restarts read them
            (self.out_dir / name).unlink(missing_ok=True)
        config_path = self.out_dir / CONFIG_FILE
        config_path.write_text(self.config.to_json())
        system = self.config.system
        session = self.session = open_session(zenoh_config([self.endpoint], mode="router"), "abyss up")
        self._change_state()  # state.json names the endpoint once it takes connections
        self.record = ControlRecorder(self.out_dir)
        self.testbed = station_recorder(self.config, TESTBED)
        observers = [
            *(session.declare_subscriber(key, self._on_observed) for key in keys.observation_keys(system)),
            session.liveliness().declare_subscriber(
                keys.key(system, "*", "alive"), self._on_alive, history=True
            ),
            session.declare_subscriber(keys.mission_key(system), self._on_status),
            session.declare_subscriber(keys.simulation_status_key(system), self._on_status),
            session.declare_subscriber(keys.onboard_state_key(system), self._on_status),
            session.declare_subscriber(keys.truth_key(system), self._on_status),
            session.declare_subscriber(keys.panel_truth_key(system), self._on_status),
            *([clock_follow(session, system, self.sim_clock)] if self.sim_clock is not None else []),
        ]
        previous = {
            s: signal.signal(s, lambda *_: self.interrupted.set()) for s in (signal.SIGINT, signal.SIGTERM)
        }
        t0 = time.monotonic()
        failure, startup_s = "", 0.0
        self.keep_running = keep_running
        try:
            self.echo(
                f"abyss: system {system}; Zenoh endpoint {self.endpoint} "
                f"(connect your own client here); run directory {self.out_dir}"
            )
            for name in keys.STATIONS:
                if name in self.external:
                    self._change_state(name, external=True)
                    self.echo(
                        f"abyss: waiting for external station {name}: start it with `abyss station "
                        f"{name} --system {system} --connect {self.endpoint}`"
                    )
                else:
                    self.stations[name] = self._start(name, config_path)
                if name == self.config.ros2.station:
                    self.echo(ros2_line(self.config.ros2))
            failure = self._wait_until_up(t0)
            startup_s = time.monotonic() - t0
            self.up_s = time.monotonic()
            if not failure and not self.interrupted.is_set():
                self.echo(f"abyss: all {len(keys.STATIONS)} stations up in {startup_s:.1f} s")
                viewer = viewer_line(self.config.onshore)
                self.echo(viewer)
                self._change_state(phase="up", viewer=viewer.removeprefix("abyss: "))
                failure = self._watch(duration_s, keep_running)
        finally:
            self._change_state(phase="stopping")
            stuck = self._stop_all()  # always: every station is stopped, whatever failed
            failure = failure or stuck
            self.cpu.close()
            for observer in observers:
                observer.undeclare()
            session.close()
            self.record.close()
            if self.testbed is not None:
                self.testbed.close()
            for s, handler in previous.items():
                signal.signal(s, handler)
        summary = self._summary(time.monotonic() - t0, startup_s, failure)
        (self.out_dir / "summary.json").write_text(json.dumps(summary, indent=2))
        self._change_state(phase="ended", verdict=summary["verdict"], failure=summary["failure"])
        self.echo(render_summary(summary))
        return exit_code(summary["verdict"], keep_running)

    def _wait_until_up(self, t0: float) -> str:
        shown: set[str] = set()
        timeout_s = STARTUP_TIMEOUT_S + (EXTERNAL_TIMEOUT_S if self.external else 0.0)
        while time.monotonic() - t0 < timeout_s:
            with self._lock:
                alive = set(self.alive)
            for name in sorted(alive - shown):
                pid = self.stations[name].process.pid if name in self.stations else "external"
                self.echo(f"abyss:   {name} up (pid {pid}, {time.monotonic() - t0:.1f} s)")
            shown |= alive
            if alive >= set(keys.STATIONS):
                return ""
            for station in self._check_deaths():
                self._report_death(station)
                return f"{station.name} died during start-up"
            if self.interrupted.wait(0.05):
                return ""  # the verdict says interrupted
        missing = sorted(set(keys.STATIONS) - shown)
        return f"not up after {timeout_s:g} s: {', '.join(missing)}"

    def _now_s(self) -> float:
        """The run's time: the wall clock's, or the simulation's with simulated time."""
        return self.sim_clock.now_s() if self.sim_clock is not None else time.monotonic()

    def _watch(self, duration_s: float | None, keep_running: bool) -> str:
        # simulated time counts from the simulation's start, which waits for every station
        t0, wall0 = 0.0 if self.sim_clock is not None else self._now_s(), time.monotonic()
        self.watch_from = (t0, wall0)
        last_report = next_start_s = wall0
        if self.replayed is not None:
            self.replay_start = ReplayStart(time.time() + REPLAY_DELAY_S)
            self.echo(
                f"abyss: replaying {', '.join(self.replayed.stations)} of {self.replayed.run_dir} "
                f"from t={REPLAY_DELAY_S:g} s (speed {self.replayed.speed:g})"
            )
        while True:
            if self.replay_start is not None and time.monotonic() >= next_start_s:
                next_start_s = time.monotonic() + 1.0  # again each second, for a replayer that starts late
                self._put(keys.replay_key(self.config.system), self.replay_start)
            for station in self._check_deaths():
                self._report_death(station)
                if not self.restart:
                    return f"{station.name} died"
                self._restart(station)
            mission = self.mission
            elapsed = self._now_s() - t0
            # done when shore says so and the simulation's truth agrees
            done = mission is not None and mission.done and self._interventions_true()
            if done and self.mission_done_s is None:
                self.mission_done_s = elapsed
                self.mission_done_wall_s = time.monotonic() - wall0
                self._change_state(mission_done=True)
                self.echo(
                    f"abyss: mission complete at t={elapsed:.1f} s"
                    + (
                        f" simulated, {self.mission_done_wall_s:.1f} s of wall time"
                        if self.sim_clock is not None
                        else ""
                    )
                )
            if done and not keep_running:
                return ""
            if duration_s is not None and elapsed >= duration_s:
                return ""
            if time.monotonic() - last_report >= 5.0:
                last_report = time.monotonic()
                state = "no telemetry on shore yet"
                if mission:
                    state = (
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
                        + (
                            "; done on shore, not in the simulation's truth"
                            if mission.done and not done
                            else ""
                        )
                    )
                self.echo(f"abyss: t={elapsed:5.0f} s{self._speed_note(wall0)}  mission: {state}")
            if self.interrupted.wait(0.1):
                self.echo("abyss: interrupted; stopping the stations")
                return ""  # the verdict says interrupted unless the mission was already done

    def _speed_note(self, wall0: float) -> str:
        """With simulated time: the speed so far, e.g. ` (x3.8)`."""
        if self.sim_clock is None or self.watch_from is None or time.monotonic() <= wall0:
            return ""
        return f" (x{(self._now_s() - self.watch_from[0]) / (time.monotonic() - wall0):.1f})"

    def time_summary(self) -> dict[str, Any]:
        """The run's time source and, with simulated time, the speed achieved and the station that
        held the simulation back the longest (`held_s`: wall seconds the simulation waited on each)."""
        summary: dict[str, Any] = {"mode": self.time.mode, "speed": self.time.speed}
        if self.sim_clock is None or self.watch_from is None:
            return summary
        sim_s, wall_s = self._now_s() - self.watch_from[0], time.monotonic() - self.watch_from[1]
        held = dict(self.simulation.held_s) if self.simulation else {}
        speed = sim_s / wall_s if wall_s > 0 else 0.0
        if self.time.mode == "lockstep":
            limited_by = "each period's slowest station"  # the periods follow each other at once
        elif speed >= 0.95 * self.time.speed_factor:
            limited_by = "speed asked"
        else:  # the station it waited on the longest; else its own physics and rendering
            limited_by = max(held, key=lambda s: held[s]) if held and max(held.values()) > 0 else "simulation"
        return {
            **summary,
            "sim_s": round(sim_s, 3),
            "wall_s": round(wall_s, 3),
            "achieved_speed": round(speed, 3),
            "held_s": held,
            "limited_by": limited_by,
        }

    def _interventions(self) -> list[dict[str, Any]]:
        start, last = self.panel if self.panel else (None, None)
        return interventions_summary(self.config.mission, start, last)

    def _interventions_true(self) -> bool:
        return all(i["success"] for i in self._interventions())

    def _summary(self, wall_s: float, startup_s: float, failure: str) -> dict[str, Any]:
        stations: dict[str, Any] = {}
        links: dict[str, dict[str, Any]] = {hop: {} for hop in keys.HOPS}
        for name, station in self.stations.items():
            status = read_json(station.status_path)
            for hop, stats in status.pop("links", {}).items():
                links[hop][stats["direction"]] = stats
            code = station.died if station.died is not None else station.process.returncode
            stations[name] = {
                "exit_code": code,
                "restarts": station.restarts,
                "stop_s": status.get("stop_s"),
                "stop_cut": status.get("stop_cut", False),
                "alive_seen": name in self.alive_seen,
                "log": str(station.log_path),
                **{
                    k: status.get(k, {})
                    for k in ("sent", "received", "rejected", "latency_ms", "cpu", "shed", "loops")
                },
                "scheduler": status.get("scheduler", ""),
            }
            if name in self.cpu.caps:
                stations[name]["cpu"] = {
                    **stations[name]["cpu"],
                    "cap_cores": self.cpu.caps[name],
                    "throttled_share": round(self.cpu.throttled_share.get(name, 0.0), 4),
                }
        for name in self.external:
            stations[name] = {"external": True, "alive_seen": name in self.alive_seen}
        if not failure and any(s.get("exit_code", 0) != 0 for s in stations.values()):
            failure = "a station exited with an error"
        return {
            "system": self.config.system,
            "endpoint": self.endpoint,
            "verdict": verdict_of(failure, self.mission_done_s is not None, self.interrupted.is_set()),
            "failure": failure,
            "keep_running": self.keep_running,
            "restarts": [outage.summary() for outage in self.restarts],
            "startup_s": round(startup_s, 3),
            "wall_s": round(wall_s, 3),
            "stations": stations,
            "links": links,
            "mission": dataclasses.asdict(self.mission) if self.mission else None,
            "mission_done_s": self.mission_done_s,
            "mission_done_wall_s": self.mission_done_wall_s,
            "time": self.time_summary(),
            "external": list(self.external),
            "control": control_summary(self.record.last if self.record else None),
            "navigation": self.nav_error.summary(),  # onboard's position error [m]
            "interventions": self._interventions(),
            "simulation": dataclasses.asdict(self.simulation) if self.simulation else None,
            "scene": read_json(self.out_dir / "scene.json"),
            "events": read_json_list(self.out_dir / EVENTS_FILE),  # the restarts as shore saw them
        }


def viewer_line(cfg: OnshoreConfig) -> str:
    from abyss.stations.onshore.viewer import RECORDING_FILE, web_viewer_url

    recording = Path(cfg.record_dir) / RECORDING_FILE
    return {
        "save": f"abyss: recording to {recording} (abyss view {cfg.record_dir})",
        "web": f"abyss: web viewer at {web_viewer_url(cfg.viewer_web_port, cfg.viewer_grpc_port)} "
        f"(recording to {recording})",
        "spawn": f"abyss: rerun viewer spawned (recording to {recording})",
        "none": "abyss: no viewer, no recording",
    }[cfg.viewer]


def ros2_line(ros2: Ros2Config) -> str:
    """How a ROS 2 node joins the gateway that stands for a station (README: ROS 2 nodes)."""
    endpoint = (ros2.connect or ros2.listen)[0]
    where = "its router" if not ros2.connect else "the router it joined"
    return (
        f"abyss: {ros2.station} is a ROS 2 gateway (domain {ros2.domain}, topics under "
        f"{ros2.namespace}); start your node with RMW_IMPLEMENTATION=rmw_zenoh_cpp "
        f"ROS_DOMAIN_ID={ros2.domain} "
        f"ZENOH_CONFIG_OVERRIDE='connect/endpoints=[\"{endpoint}\"]' ({where}) and use_sim_time:=true"
    )


def run_up(
    config: Config,
    out: Path | None,
    duration_s: float | None,
    keep_running: bool,
    port: int | None,
    external: Sequence[str] = (),
    restart: bool = False,
    placement: Placement | None = None,
    replayed: Replayed | None = None,
) -> int:
    run_dir = out or Path("runs") / f"{config.system}-{time.strftime('%Y%m%d-%H%M%S')}"
    try:
        return Up(
            config, run_dir, port, external=external, restart=restart, placement=placement, replayed=replayed
        ).run(duration_s, keep_running)
    except AbyssError as exc:
        print(f"abyss: {exc}", file=sys.stderr)
        return 2
