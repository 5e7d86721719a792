"""Running one station: the same code path for `abyss station` and `abyss up`."""

from __future__ import annotations

import contextlib
import ctypes
import faulthandler
import importlib
import io
import json
import logging
import math
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import zenoh
from threadpoolctl import threadpool_limits

from abyss.bus import description
from abyss.bus.session import Bus, open_session, zenoh_config
from abyss.common.leave import STOP_BOUND_S, watch_the_stop
from abyss.common.workers import Workers, children_cpu_s, loops_first
from abyss.config import Config, robot_of, site_of
from abyss.interface import keys
from abyss.interface.messages import repeatable_ids
from abyss.interface.system_description import description_payload
from abyss.linkemu.control import StationLinks
from abyss.recording.store import Caps, Recorder, free_recording_path
from abyss.security import access
from abyss.security.certs import CertFiles
from abyss.timing.clock import WALL, Clock, ProgressReport, SimClock
from abyss.timing.clock import follow as clock_follow
from abyss.timing.lockstep import TESTBED, Lockstep, LockstepClock

log = logging.getLogger(__name__)
SUPERVISOR_ENV = "ABYSS_SUPERVISOR_PID"  # set by `abyss up` for the stations it starts
BOOT_ENV = "ABYSS_BOOT"  # how many times `abyss up` started this station before (restarts)
PR_SET_PDEATHSIG = 1


def stop_with_supervisor() -> None:
    """A station that `abyss up` started is sent SIGTERM when `abyss up` dies, even by SIGKILL
    (Linux), so that no station outlives its system."""
    pid = os.environ.get(SUPERVISOR_ENV)
    if not pid or not sys.platform.startswith("linux"):
        return
    ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
    if os.getppid() != int(pid):  # it died before the line above
        os.kill(os.getpid(), signal.SIGTERM)


def station_entry(name: str) -> Callable[[Config, Any], None]:
    """The station's `run(config, bus)`."""
    return importlib.import_module(f"abyss.stations.{keys.check_station(name)}").run


def station_main(name: str, config: Config) -> Callable[[Config, Any], None]:
    """What runs in station `name`'s shell: the station's `run(config, bus)`, or with
    `ros2.station` naming it (onboard, the vessel or the simulation, as the config allows), the
    ROS 2 gateway (abyss.ros2.gateway): in onboard's place; beside the vessel, whose scene model
    then adopts each map the ROS 2 node publishes; or beside the simulation's twin, the node
    being a real vehicle's driver (a hybrid run)."""
    if config.ros2.station != name:
        return station_entry(name)
    if name == "vessel":
        return _vessel_with_gateway
    if name == "simulation":
        return _twin_with_gateway
    from abyss.ros2 import gateway

    return gateway.run


def _vessel_with_gateway(config: Config, bus: Bus) -> None:
    """The vessel with a ROS 2 node for its scene model: the gateway hands the node the clouds,
    and each map the node publishes to the vessel's model (`adopt`)."""
    from abyss.ros2.gateway import Gateway
    from abyss.stations import vessel

    def mapper(adopt: Callable[[Any], object]) -> Gateway:
        return Gateway(config, bus, on_up={"scene": adopt})

    vessel.run(config, bus, mapper=mapper)


def _twin_with_gateway(config: Config, bus: Bus) -> None:
    """The simulation with a real vehicle's ROS 2 driver (`--ros2 simulation`, a hybrid run): the
    gateway, in a worker, puts the driver's navigation and joints on the simulation's keys (to
    onboard, and to the twin, which takes them from its own session) and hands it the velocity
    commands; the station runs as usual, which in a hybrid run is the twin."""
    from abyss.ros2.gateway import Gateway

    gateway = Gateway(config, bus)
    try:
        with Workers(bus.stop) as workers:
            workers.start("ros2 gateway", gateway.run)
            station_entry("simulation")(config, bus)
    finally:
        gateway.close()


class Shell:
    """What hosts one station in the testbed: its Zenoh session, the bus the station sees, the
    links behind that bus (emulated or netem, with their control plane), its liveliness token and
    the running system's description it serves the operator's tools (bus.description). `close()`
    undoes it all, links first, so that nothing blocks on a link."""

    def __init__(
        self,
        name: str,
        config: Config,
        listen: Sequence[str] = (),
        connect: Sequence[str] = (),
        link_mode: str = "emulated",
        mode: str = "peer",
        tls_dir: Path | None = None,
        peers: dict[str, str] | None = None,
    ) -> None:
        self.started_s, self.started_cpu_s = time.monotonic(), time.process_time() + children_cpu_s()
        profiles = config.links.profiles()
        tls = CertFiles(tls_dir, name) if tls_dir else None
        slowest_bps = min(profiles[hop].rate_bps for hop in keys.hops_of(name))
        settings = zenoh_config(
            listen, connect, mode, tls=tls, acl_station=name if tls else None, slowest_rate_bps=slowest_bps
        )  # bad endpoints or certificates fail here
        self.refusals = access.refusal_log() if tls is not None else None
        self.session = open_session(settings, f"station {name}")
        self.clock, self._clock_closers = station_clock(self.session, config, name)
        self.bus = Bus(config.system, name, self.session, self.clock)
        self.links = StationLinks(
            self.session,
            config.system,
            name,
            profiles,
            self.bus.transmit,
            seed=config.seed,
            link_mode=link_mode,
            peers=peers,
            stopping=self.bus.stop,
            clock=self.clock,
        )
        for hop in self.links.runners:
            self.bus.route(hop, self.links.egress(hop))
        self.recorder = station_recorder(config, name, self.clock)
        self.bus.tap = self.recorder
        if isinstance(self.clock, LockstepClock):
            repeatable_ids([config.seed, keys.STATIONS.index(name), int(os.environ.get(BOOT_ENV, "0"))])
            self.bus.lockstep = station_lockstep(
                self.session, config, name, self.clock, self.bus, self.links, self.recorder
            )
            self._clock_closers.append(self.bus.lockstep.close)
            if name != "simulation":  # the simulation's physics is lockstep's master, and runs its own
                threading.Thread(target=self.bus.lockstep.run, name="lockstep", daemon=True).start()
        self._token = self.session.liveliness().declare_token(keys.alive_key(config.system, name))
        # what the system runs by, for the operator's tools (as ROS's robot_description)
        payload = description_payload(config.system, robot_of(config), site_of(config))
        self._description = description.serve(self.session, config.system, name, payload)

    def status(self) -> dict[str, Any]:
        status = self.bus.status()
        status["rejected"] = {**status["rejected"], **self.links.rejected}
        status["refused"] = dict(self.refusals.refused) if self.refusals else {}
        status["links"] = self.links.status()
        if self.recorder is not None:
            status["recording"] = self.recorder.status()
        wall_s = time.monotonic() - self.started_s
        cpu_s = time.process_time() + children_cpu_s() - self.started_cpu_s  # its sensor processes too
        status["cpu"] = {
            "cpu_s": round(cpu_s, 3),
            "wall_s": round(wall_s, 3),
            "cores": round(cpu_s / wall_s, 4) if wall_s > 0 else 0.0,
        }  # all its threads
        return status

    def close(self, drain_s: float = 0.0) -> None:
        """Links first (no sender waits on them any more; what is in flight is counted), then
        the station's keys and the session."""
        self.bus.stop.set()
        self.links.close(drain_s)
        self._token.undeclare()
        self._description.undeclare()
        for close in self._clock_closers:
            close()
        self.bus.close()
        if self.recorder is not None:
            self.recorder.close()
        self.session.close()


def station_clock(
    session: zenoh.Session, config: Config, name: str
) -> tuple[Clock, list[Callable[[], None]]]:
    """The station's clock: the wall clock, or (`time.mode` sim) the simulation's time, which the
    simulation ticks itself and every other station follows, telling how far its loops are done;
    and what closes it with the station."""
    if not config.time.simulated:
        return WALL, []
    clock = (
        LockstepClock()
        if config.time.mode == "lockstep"
        else SimClock(
            config.simulation.control_period_s if math.isfinite(config.time.speed_factor) else 0.0,
            config.time.speed_factor,
        )
    )
    if name == "simulation":
        return clock, []
    ticks = clock_follow(session, config.system, clock)
    if isinstance(clock, LockstepClock):
        return clock, [ticks.undeclare]
    return clock, [ticks.undeclare, ProgressReport(session, config.system, name, clock).close]


def station_lockstep(
    session: zenoh.Session,
    config: Config,
    name: str,
    clock: LockstepClock,
    bus: Bus,
    links: StationLinks,
    recorder: Recorder | None,
) -> Lockstep:
    """A station's periods in lockstep: its links' deliveries, its neighbours', its loops, its
    holds (its recording flushed before each)."""

    def expects() -> dict[str, set[str]]:
        listened = bus.data_keys()
        return {
            neighbour: {s.key(config.system) for s in keys.KEYS if s.station == neighbour and s.to == name}
            & listened
            for neighbour in keys.hops_of(name).values()
        }

    lockstep = Lockstep(
        session,
        config.system,
        name,
        clock,
        links.deliver_due,
        bus.arrivals,
        expects,
        importlib.import_module(f"abyss.stations.{name}").loops(config),
        bus.stop,
        bus.reject,
        holds_s=config.time.holds_s,
        period_s=config.simulation.control_period_s,
        end_s=config.time.end_s,
        boot=int(os.environ.get(BOOT_ENV, "0")),
        before_hold=recorder.flush if recorder is not None else lambda: None,
        listens=("*",)
        if name == "simulation"
        else (*keys.hops_of(name).values(), *((TESTBED,) if config.time.phase_holds else ())),
        phase_leased=config.time.phase_holds and name == "simulation",
    )
    bus.on_arrival = lockstep.notify
    return lockstep


def station_recorder(config: Config, name: str, clock: Clock = WALL) -> Recorder | None:
    """The recorder of `name`'s bus, where the run records (`record.directory`, `record.level`)."""
    record = config.record
    if not record.directory or record.level == "none":
        return None
    return Recorder(
        free_recording_path(Path(record.directory), name),
        name,
        config.system,
        record.level,
        Caps(record.max_rate_hz, record.bulk_max_rate_hz),
        clock,
    )


NATIVE_POOLS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def single_threaded_native_pools() -> None:
    """One thread for the native libraries' own pools (numpy's OpenBLAS, OpenMP in Open3D): a
    station is one of many processes on the machine, and a pool's threads spin between calls (on
    onboard's clouds: 216 ms of CPU per stereo pair with numpy's two threads, 122 ms with one, the
    same wall time). They also add floating-point sums in whatever order their threads finish, a
    last-bit difference lockstep would carry on. A user's own setting of these variables stands;
    libraries loaded later read them, the ones loaded already are limited now."""
    for name in NATIVE_POOLS:
        os.environ.setdefault(name, "1")
    threadpool_limits(int(os.environ["OPENBLAS_NUM_THREADS"]))


class _StopSignals:
    """SIGINT and SIGTERM ask the station to stop (`stop`), once its shell is up; a watchdog
    (`_stop_watchdog`) then holds the stop to STOP_BOUND_S. The handler takes no lock: it runs in
    the main thread between two of its bytecodes, maybe inside bus.stop.wait() with the event's
    lock half taken, which set() takes too (a deadlock that once left a station to its
    watchdog). It writes the signal to a pipe; a thread of its own reads it and asks for the
    stop."""

    def __init__(self, name: str, status_file: Path | None) -> None:
        self.name, self.status_file = name, status_file
        self.asked_s: list[float] = []  # when the stop was asked for (this process's monotonic clock)
        self.stopped = threading.Event()
        self.outcome: dict[str, Any] = {"exit_code": 0}  # what the watchdog writes if it has to cut the stop
        self.stop: threading.Event | None = None  # the bus's, once the shell is up
        self._read, self._write = os.pipe()
        threading.Thread(target=self._watch, name="signals", daemon=True).start()

    def install(self, stop: threading.Event) -> None:
        self.stop = stop
        if threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGINT, self._handler)
            signal.signal(signal.SIGTERM, self._handler)
            stop_with_supervisor()

    def _handler(self, signum: int, _frame: Any) -> None:
        os.write(self._write, bytes([signum]))

    def _watch(self) -> None:
        while data := os.read(self._read, 1):
            self._asked(data[0])

    def _asked(self, signum: int) -> None:
        log.info("%s: %s received, stopping", self.name, signal.Signals(signum).name)
        if not self.asked_s:
            threading.Thread(
                target=_stop_watchdog,
                args=(self.name, self.stopped, self.status_file, self.outcome),
                name="stop watchdog",
                daemon=True,
            ).start()
        self.asked_s.append(time.monotonic())
        assert self.stop is not None  # the handlers are installed with it
        self.stop.set()


def run_station(
    name: str,
    config: Config,
    listen: Sequence[str],
    connect: Sequence[str],
    status_file: Path | None,
    link_mode: str = "emulated",
    mode: str = "peer",
    tls_dir: Path | None = None,
    peers: dict[str, str] | None = None,
    entry: Callable[[Config, Any], None] | None = None,
) -> int:
    """Open the shell, run the station (`station_main`, or `entry` in its place: a replay) until
    SIGINT/SIGTERM, close, write the status file."""
    entry = entry or station_main(name, config)
    single_threaded_native_pools()
    loops_first()
    signals = _StopSignals(name, status_file)
    shell = Shell(name, config, listen, connect, link_mode, mode, tls_dir, peers)
    signals.install(shell.bus.stop)
    log.info(
        "%s up in system %s as a Zenoh %s (listen %s, connect %s%s)",
        name,
        config.system,
        mode,
        list(listen),
        list(connect),
        ", TLS and access control" if tls_dir else "",
    )
    code = 0
    try:
        entry(config, shell.bus)
    except Exception:
        log.exception("%s failed", name)
        code = 1
    signals.asked_s.append(time.monotonic())
    signals.outcome.update(exit_code=code, **shell.status())  # the counters so far, should the close hang
    shell.close()  # the links first: nothing still in flight is waited for, only counted
    status = {**shell.status(), "stop_s": round(time.monotonic() - signals.asked_s[0], 3)}  # from the signal
    if status_file is not None:
        status_file.write_text(json.dumps({"exit_code": code, **status}, indent=2))
    signals.stopped.set()
    log.info("%s stopped (exit %d)", name, code)
    return code


def _stop_watchdog(
    name: str, stopped: threading.Event, status_file: Path | None, outcome: dict[str, Any]
) -> None:
    """A station stops within STOP_BOUND_S of being asked, whatever hangs: past it, the status is
    written from the counters taken before the close, marked `stop_cut` (common.leave)."""

    def last_words() -> int:
        if status_file is not None:
            status_file.write_text(
                json.dumps({**outcome, "stop_s": STOP_BOUND_S, "stop_cut": True}, indent=2)
            )
        return int(outcome["exit_code"])

    watch_the_stop(name, stopped, last_words)


def configure_logging(verbose: bool = False) -> None:
    """A station's log on stderr, where SIGUSR1 also writes every thread's stack (a scenario run
    that stood still asks for them before it kills the run)."""
    logging.basicConfig(
        level=logging.DEBUG if verbose else logging.INFO,
        stream=sys.stderr,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    with contextlib.suppress(io.UnsupportedOperation, ValueError):  # a stderr that is no file: none
        faulthandler.register(signal.SIGUSR1, file=sys.stderr, all_threads=True)
