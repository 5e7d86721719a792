"""`abyss up`: the four stations as four OS processes on this machine. `Up` composes the parts:
start (`launch.start`), what the supervisor hears (`launch.observe`), supervise
(`launch.supervise`), stop (`launch.stop`) and summarise (`launch.summarise`, `launch.verdict`)."""

from __future__ import annotations

import dataclasses
import json
import os
import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import zenoh

from abyss.bus.session import open_session, zenoh_config
from abyss.common.errors import AbyssError
from abyss.config import Config, site_of
from abyss.console.server import Console
from abyss.interface import keys
from abyss.launch.cpu import CpuCaps
from abyss.launch.mission_check import check_reach
from abyss.launch.observe import Heard
from abyss.launch.start import (
    Local,
    Placement,
    Replayed,
    Starter,
    checked_external,
    endpoint_of,
    prepare_run_dir,
    run_config,
    viewer_line,
)
from abyss.launch.state import RunState
from abyss.launch.stop import interrupts_to, stop_all
from abyss.launch.summarise import Ending, run_summary
from abyss.launch.supervise import Supervisor
from abyss.launch.verdict import exit_code, render_summary
from abyss.timing.clock import SimClock


class Up:
    """Start, watch and stop one whole system; write its summary."""

    def __init__(
        self,
        config: Config,
        out_dir: Path,
        port: int | None = None,
        echo: Callable[[str], None] | None = None,
        external: Sequence[str] = (),
        restart: bool = False,
        placement: Placement | None = None,
        replayed: Replayed | None = None,
        console_port: int | None = None,
    ) -> None:
        external = checked_external(config, external, restart, replayed)
        check_reach(config)  # a mission its arm cannot work fails here, not a minute in
        self.config = config
        self.cpu = CpuCaps(config.system, config.cpu.capped())  # fails here where no cgroup can be made
        self.out_dir = out_dir.resolve()  # the stations run there, whatever the caller's directory
        self.echo = echo or (lambda text: print(text, flush=True))
        self.endpoint = endpoint_of(config, port)
        self.interrupted = threading.Event()
        self.keep_running = False
        self.console_port = console_port  # the pilot's console's, once up (None: no console)
        self.console: Console | None = None
        self.state = RunState(config.system, self.endpoint, os.getpid())
        self._state_lock = threading.Lock()
        self.heard = Heard(self.change_state)
        starter = Starter(
            self.out_dir,
            self.endpoint,
            config.time,
            self.cpu,
            self.change_state,
            placement or Local(),
            replayed,
        )
        self.supervisor = Supervisor(
            config,
            starter,
            self.heard,
            self.echo,
            self.interrupted,
            self.change_state,
            external=external,
            restart=restart,
            sim_clock=SimClock(config.simulation.control_period_s, config.time.speed_factor)
            if config.time.simulated
            else None,
            replayed=replayed,
        )

    def change_state(self, station: str | None = None, **changes: Any) -> None:
        """Change the run's state (or one station's in it) and write `state.json` at once, under
        the lock: Zenoh's callbacks change it too."""
        with self._state_lock:
            if station is None:
                self.state = dataclasses.replace(self.state, **changes)
            else:
                self.state = self.state.with_station(station, **changes)
            if self.out_dir.is_dir():
                self.state.write(self.out_dir)

    def run(self, duration_s: float | None, keep_running: bool) -> int:
        self.config = self.supervisor.config = run_config(self.config, self.out_dir, duration_s, self.echo)
        prepare_run_dir(self.out_dir, self.config)
        session = self.supervisor.session = open_session(
            zenoh_config([self.endpoint], mode="router"), "abyss up"
        )
        self.change_state()  # state.json names the endpoint once it takes connections
        self.heard.open(self.out_dir, self.config)
        observers = self.heard.declare(session, self.config.system, self.supervisor.sim_clock)
        self.keep_running = keep_running
        with interrupts_to(self.interrupted):
            t0 = time.monotonic()
            failure, startup_s = "", 0.0
            try:
                failure, startup_s = self._start_and_watch(t0, duration_s, keep_running)
            finally:
                self.change_state(phase="stopping")
                if self.console is not None:
                    self.console.close()
                stuck = stop_all(self.supervisor.stations.values(), self.echo)  # always, whatever failed
                failure = failure or stuck
                self._close(session, observers)
        summary = self.summary(time.monotonic() - t0, startup_s, failure)
        (self.out_dir / "summary.json").write_text(json.dumps(summary, indent=2))
        self.change_state(phase="ended", verdict=summary["verdict"], failure=summary["failure"])
        self.echo(render_summary(summary))
        return exit_code(summary["verdict"], keep_running)

    def _start_and_watch(self, t0: float, duration_s: float | None, keep_running: bool) -> tuple[str, float]:
        """The failure ('' for none) and how long the stations took to come up [s]."""
        self.echo(
            f"abyss: system {self.config.system}; Zenoh endpoint {self.endpoint} "
            f"(connect your own client here); run directory {self.out_dir}"
        )
        self.supervisor.start_all()
        # an external station may never come: the run's duration bounds the wait for it too
        failure = self.supervisor.wait_until_up(t0, duration_s if not self.config.time.simulated else None)
        startup_s = time.monotonic() - t0
        self.supervisor.up_s = time.monotonic()
        if not failure and not self.interrupted.is_set() and not self.supervisor.never_came:
            self.echo(f"abyss: all {len(keys.STATIONS)} stations up in {startup_s:.1f} s")
            viewer = viewer_line(self.config.onshore)
            self.echo(viewer)
            session = self.supervisor.session
            if self.console_port is not None and session is not None:  # abyss up's, on shore's network
                from abyss.stations.onshore.viewer import web_viewer_url  # rerun: only here

                onshore = self.config.onshore
                web = onshore.viewer == "web"
                self.console = Console(
                    session,
                    self.config.system,
                    self.console_port,
                    site_of(self.config).panel,
                    viewer_url=web_viewer_url(onshore.viewer_web_port, onshore.viewer_grpc_port)
                    if web
                    else "",
                )
                self.echo(f"abyss: the pilot's console at {self.console.url}")
            self.change_state(phase="up", viewer=viewer.removeprefix("abyss: "))
            failure = self.supervisor.watch(duration_s, keep_running)
        return failure, startup_s

    def _close(self, session: zenoh.Session, observers: list[Any]) -> None:
        self.cpu.close()
        for observer in observers:
            observer.undeclare()
        session.close()
        self.heard.close()

    def summary(self, wall_s: float, startup_s: float, failure: str) -> dict[str, Any]:
        """`summary.json`'s table, once every station stopped."""
        ending = Ending(wall_s, startup_s, failure, self.interrupted.is_set(), self.keep_running)
        return run_summary(self.config, self.endpoint, self.out_dir, self.supervisor, self.cpu, ending)


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
    console_port: int | None = None,
) -> int:
    run_dir = out or Path("runs") / f"{config.system}-{time.strftime('%Y%m%d-%H%M%S')}"
    try:
        return Up(
            config,
            run_dir,
            port,
            external=external,
            restart=restart,
            placement=placement,
            replayed=replayed,
            console_port=console_port,
        ).run(duration_s, keep_running)
    except AbyssError as exc:
        print(f"abyss: {exc}", file=sys.stderr)
        return 2
