"""What `abyss up`'s supervisor hears over Zenoh: which stations are alive, shore's mission
status, the simulation's status and truth, onboard's telemetry, the panel's truth; and how far
the vehicle strays while a restarted station is down."""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from abyss.common.errors import BadMessage
from abyss.config import Config, site_of
from abyss.interface import keys
from abyss.interface.messages import MissionStatus, NavState, PanelState, SimulationStatus, Telemetry, decode
from abyss.launch.control_record import ControlRecorder
from abyss.launch.station import station_recorder
from abyss.launch.verdict import NavError, hybrid_interventions, interventions_summary
from abyss.recording.store import TESTBED, Recorder
from abyss.timing.clock import SimClock
from abyss.timing.clock import follow as clock_follow

# a restarted station is back when its session is up and, for these, once its output is seen
# again (onboard's telemetry, the simulation's truth): a session comes up before the station runs
# what says a restarted station is back: its output the supervisor sees (the simulation's truth; a
# hybrid run's twin, which has none, its status)
HEARD_FROM: dict[str, tuple[type, ...]] = {
    "onboard": (Telemetry,),
    "simulation": (NavState, SimulationStatus),
}


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


class Heard:
    """The supervisor's observers (Zenoh's callbacks) and what they found. `lock` guards what
    the callbacks and the supervisor's thread both change."""

    def __init__(self, change_state: Callable[..., None]) -> None:
        self.change_state = change_state  # a station's `up` in the run's state
        self.lock = threading.Lock()
        self.alive: set[str] = set()
        self.alive_seen: set[str] = set()
        self.mission: MissionStatus | None = None
        self.simulation: SimulationStatus | None = None
        self.record: ControlRecorder | None = None
        self.testbed: Recorder | None = None  # the observation keys' recording
        self.down: dict[str, Outage] = {}  # restarts whose station is not back yet
        self.truth_m_world: np.ndarray | None = None  # the vehicle's position, from the simulation
        self.truth_s = -math.inf  # [simulated s] the latest truth's; the panel's came before it
        self.nav_error = NavError()  # onboard's estimate against it
        self.panel: tuple[PanelState, PanelState] | None = None  # the panel's truth: the first, the latest

    def open(self, out_dir: Path, config: Config) -> None:
        """The control recording and the testbed's recording of the observation keys."""
        self.record = ControlRecorder(out_dir)
        self.testbed = station_recorder(config, TESTBED)

    def close(self) -> None:
        if self.record is not None:
            self.record.close()
        if self.testbed is not None:
            self.testbed.close()

    def declare(self, session: zenoh.Session, system: str, sim_clock: SimClock | None) -> list[Any]:
        """Every observer on `session`, to undeclare when the run ends."""
        statuses = (
            keys.mission_key(system),
            keys.simulation_status_key(system),
            keys.onboard_state_key(system),
            keys.truth_key(system),
            keys.panel_truth_key(system),
        )
        return [
            *(session.declare_subscriber(key, self.on_observed) for key in keys.observation_keys(system)),
            session.liveliness().declare_subscriber(
                keys.key(system, "*", "alive"), self.on_alive, history=True
            ),
            *(session.declare_subscriber(key, self.on_status) for key in statuses),
            *([clock_follow(session, system, sim_clock)] if sim_clock is not None else []),
        ]

    def on_alive(self, sample: zenoh.Sample) -> None:
        name = str(sample.key_expr).split("/")[2]
        with self.lock:
            if sample.kind == zenoh.SampleKind.PUT:
                self.alive.add(name)
                self.alive_seen.add(name)
                if name in self.down:  # its session is back; it is up once it is heard from
                    self.down[name].alive = True
                    if name not in HEARD_FROM:
                        self.back(name)
            else:
                self.alive.discard(name)
            self.change_state(name, up=name in self.alive)

    def on_status(self, sample: zenoh.Sample) -> None:
        """Mission status from shore, simulation status from the simulation, the controllers'
        telemetry from onboard."""
        try:
            message = decode(str(sample.key_expr), sample.payload.to_bytes()).message
        except BadMessage:
            return
        if isinstance(message, NavState):  # the simulation's truth
            self._on_truth(message)
        with self.lock:
            for name, kind in HEARD_FROM.items():
                if isinstance(message, kind) and name in self.down and self.down[name].alive:
                    self.back(name)
        if isinstance(message, PanelState):
            self.panel = (self.panel[0] if self.panel else message, message)
            if self.record is not None:
                self.record.add(message)
        if isinstance(message, MissionStatus):
            self.mission = message
        elif isinstance(message, SimulationStatus):
            self.simulation = message
        elif isinstance(message, Telemetry):
            with self.lock:
                self.nav_error.add_estimate(message)
            if self.record is not None:
                self.record.add(message)

    def _on_truth(self, message: NavState) -> None:
        with self.lock:
            for down in self.down.values():
                if down.from_m_world is not None:
                    drift_m = float(np.linalg.norm(message.position_m_world - down.from_m_world))
                    down.drift_m = max(down.drift_m, drift_m)
            self.truth_m_world = message.position_m_world
            self.truth_s = message.sim_time_s
            self.nav_error.add_truth(message.sim_time_s, message.position_m_world)

    def on_observed(self, sample: zenoh.Sample) -> None:
        if self.testbed is not None:
            self.testbed.add("observed", str(sample.key_expr), sample.payload.to_bytes())

    def back(self, name: str) -> None:
        """A restarted station is up again: how long it was down (the caller holds the lock)."""
        down = self.down.pop(name)
        down.down_s = round(time.monotonic() - down.died_s, 3)

    def interventions(self, config: Config) -> list[dict[str, Any]]:
        if config.hybrid.on:  # the truth is the real world's
            return hybrid_interventions(config.mission, self.mission)
        start, last = self.panel if self.panel else (None, None)
        return interventions_summary(config.mission, site_of(config).panel, start, last)

    def interventions_true(self, config: Config) -> bool:
        """The mission's interventions done in the simulation's truth; a hybrid run has none to
        judge by, and shore's status (onboard's measurement) decides alone."""
        return config.hybrid.on or all(i["success"] for i in self.interventions(config))
