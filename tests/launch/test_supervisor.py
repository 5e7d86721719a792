"""`abyss up`'s supervisor (`launch/up.py`'s `Up` and its parts) without Zenoh: its stations stand in as short
Python processes, its observers' findings (stations alive, mission status) are set by hand.
How it notices deaths, stops its stations, waits for them, watches the run and sums it up.

(Named test_supervisor.py, not test_up.py: the e2e suite has a test_up.py, and the test folders
are not packages, so two modules of one name cannot be collected in one run.)"""

from __future__ import annotations

import dataclasses
import json
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

import pytest

from abyss.common.errors import ConfigError
from abyss.common.ports import port_free
from abyss.config import Config
from abyss.config.system import Ros2Config
from abyss.interface import keys
from abyss.interface.messages import MissionStatus, SimulationStatus
from abyss.launch import stop as stop_module
from abyss.launch import supervise as supervise_module
from abyss.launch.start import Station, ros2_line, viewer_line
from abyss.launch.state import RunState
from abyss.launch.stop import stop_all
from abyss.launch.up import Up, run_up
from abyss.launch.verdict import exit_code, render_summary, verdict_of

# children that say "ready" once their signal handlers are set, so no signal comes too early
IGNORES_SIGINT = (
    "import signal, sys\nsignal.signal(signal.SIGINT, signal.SIG_IGN)\n"
    "print('ready', flush=True)\nwhile True:\n    signal.pause()\n"
)
STOPS_ON_SIGINT = (
    "import signal, sys, time\n"
    "def stop(*_):\n    time.sleep(0.3)  # closing its links\n    sys.exit(7)\n"
    "signal.signal(signal.SIGINT, stop)\nprint('ready', flush=True)\n"
    "while True:\n    signal.pause()\n"
)
RUNS = STOPS_ON_SIGINT


class System:
    """An `Up` on a run directory under tmp_path, its echo collected, and its stations."""

    def __init__(self, tmp_path: Path, external: Sequence[str] = ()) -> None:
        self.lines: list[str] = []
        # a mission of waypoints and an arm goal: the interventions' truth is judged elsewhere
        # (test_intervention_verdict.py)
        config = Config(system="unit")
        config = dataclasses.replace(config, mission=dataclasses.replace(config.mission, interventions=()))
        self.up = Up(config, tmp_path / "run", port=0, echo=self.lines.append, external=external)
        self.up.out_dir.mkdir(parents=True)
        self.processes: list[subprocess.Popen[bytes]] = []

    def station(self, name: str, code: str) -> Station:
        """A station running `code`, once it said it is ready (when it says anything)."""
        process = subprocess.Popen(
            [sys.executable, "-c", code], stdout=subprocess.PIPE, stdin=subprocess.DEVNULL
        )
        self.processes.append(process)
        assert process.stdout is not None
        if "ready" in code:
            assert process.stdout.readline() == b"ready\n"
        station = Station(name, process, self.up.out_dir / f"{name}.log", self.up.out_dir / f"{name}.json")
        station.log_path.write_text(f"{name} starting\n")
        self.up.supervisor.stations[name] = station
        return station

    def exited(self, name: str, code: int) -> Station:
        station = self.station(name, f"raise SystemExit({code})")
        assert station.process.wait(timeout=60) == code
        return station

    def output(self) -> str:
        return "\n".join(self.lines)

    def close(self) -> None:
        for process in self.processes:
            if process.poll() is None:
                process.kill()
            process.wait()
            if process.stdout is not None:
                process.stdout.close()


@pytest.fixture
def system(tmp_path: Path) -> Iterator[Callable[..., System]]:
    made: list[System] = []

    def make(external: Sequence[str] = ()) -> System:
        made.append(System(tmp_path / str(len(made)), external))
        return made[-1]

    yield make
    for s in made:
        s.close()


def mission(done: bool) -> MissionStatus:
    return MissionStatus(
        mode="reached",
        waypoint_index=3,
        waypoints_total=3,
        position_error_m=0.01,
        heading_error_rad=0.001,
        arm_mode="reached" if done else "moving",
        ee_position_error_m=0.004,
        ee_orientation_error_rad=0.01,
        failsafe="",
        failsafe_events=0,
        done=done,
    )


# -- construction ------------------------------------------------------------------------------


def test_port_zero_picks_a_free_port_and_a_taken_port_is_seen(tmp_path: Path) -> None:
    up = Up(Config(system="unit"), tmp_path / "run", port=0, echo=lambda _: None)
    port = int(up.endpoint.rpartition(":")[2])
    assert up.endpoint.startswith("tcp/127.0.0.1:") and port > 0
    assert up.out_dir.is_absolute() and not up.out_dir.exists()  # made by run(), not before
    assert up.state == RunState("unit", up.endpoint, up.state.supervisor_pid)
    assert Up(Config(system="unit"), tmp_path, port=5555, echo=print).endpoint == "tcp/127.0.0.1:5555"
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        assert not port_free(taken.getsockname()[1])


def test_an_unknown_external_station_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(ConfigError, match="unknown station 'sonar'"):
        Up(Config(system="unit"), tmp_path / "run", port=0, external=["vessel", "sonar"])
    # and `abyss up` says so and exits 2 before it starts anything
    assert run_up(Config(system="unit"), tmp_path / "run", 1.0, False, 0, external=["sonar"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("abyss: ") and "unknown station 'sonar'" in err
    assert not (tmp_path / "run").exists()


def test_a_ros2_gateway_for_an_external_station_is_refused(tmp_path: Path) -> None:
    config = Config(system="unit", ros2=Ros2Config(station="onboard"))
    with pytest.raises(ConfigError, match="onboard is --external too"):
        Up(config, tmp_path / "run", port=0, external=["onboard"])
    assert "ROS_DOMAIN_ID=0" in ros2_line(config.ros2) and "tcp/127.0.0.1:7447" in ros2_line(config.ros2)


def test_viewer_line_names_where_to_look(tmp_path: Path) -> None:
    onshore = Config(system="unit").onshore
    assert viewer_line(dataclasses.replace(onshore, viewer="none")) == (
        "abyss: no rerun viewer, no rerun recording (the bus recording, --record, is apart)"
    )
    saved = viewer_line(dataclasses.replace(onshore, viewer="save", record_dir=str(tmp_path)))
    assert str(tmp_path) in saved and saved.startswith("abyss: recording to ")


# -- deaths ------------------------------------------------------------------------------------


def test_each_death_is_reported_once_with_its_exit_code(system: Callable[..., System]) -> None:
    s = system()
    crashed = s.exited("simulation", 3)
    running = s.station("onboard", RUNS)
    dead = s.up.supervisor.check_deaths()
    assert dead == [crashed] and crashed.died == 3 and running.died is None
    assert s.up.supervisor.check_deaths() == []  # already reported
    running.process.kill()
    running.process.wait(timeout=60)
    assert s.up.supervisor.check_deaths() == [running] and running.died == -signal.SIGKILL
    assert s.up.supervisor.check_deaths() == []


def test_a_death_is_reported_with_the_signal_and_the_end_of_the_log(system: Callable[..., System]) -> None:
    s = system()
    station = s.station("onboard", RUNS)
    station.log_path.write_text("".join(f"log line {i}\n" for i in range(40)))
    station.process.kill()
    station.process.wait(timeout=60)
    [dead] = s.up.supervisor.check_deaths()
    s.up.supervisor.report_death(dead)
    assert s.lines[0] == f"abyss: station onboard died with exit code -9 (SIGKILL); log {station.log_path}:"
    assert s.lines[1:] == [f"    log line {i}" for i in range(25, 40)]  # the last 15 lines


# -- stopping ----------------------------------------------------------------------------------


def test_stop_interrupts_every_station_and_kills_the_ones_that_do_not_stop(
    system: Callable[..., System], monkeypatch: pytest.MonkeyPatch
) -> None:
    timeout_s = 2.0
    monkeypatch.setattr(stop_module, "STOP_TIMEOUT_S", timeout_s)
    s = system()
    willing = s.station("simulation", STOPS_ON_SIGINT)  # takes 0.3 s to stop: it is waited for
    stubborn = [s.station("onboard", IGNORES_SIGINT), s.station("vessel", IGNORES_SIGINT)]
    gone = s.exited("onshore", 0)
    t0 = time.monotonic()
    stop_all(s.up.supervisor.stations.values(), s.up.echo)
    elapsed = time.monotonic() - t0
    assert willing.process.returncode == 7  # its SIGINT handler ran: SIGINT, not SIGTERM or SIGKILL
    assert [st.process.returncode for st in stubborn] == [-signal.SIGKILL] * 2
    assert gone.process.returncode == 0
    assert s.lines == [f"abyss: {name} did not stop in 2 s; killing it" for name in ("onboard", "vessel")]
    # it waits the stop timeout before killing, and that once for all stations, not once each
    assert timeout_s <= elapsed < 1.75 * timeout_s, elapsed


def test_stop_does_not_kill_stations_that_stop_in_time(
    system: Callable[..., System], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(stop_module, "STOP_TIMEOUT_S", 30.0)
    s = system()
    stations = [s.station(name, STOPS_ON_SIGINT) for name in keys.STATIONS]
    t0 = time.monotonic()
    stop_all(s.up.supervisor.stations.values(), s.up.echo)
    assert time.monotonic() - t0 < 15.0  # it does not wait the whole timeout for stopped stations
    assert [st.process.returncode for st in stations] == [7] * 4
    assert s.lines == []


# -- start-up and the watch ------------------------------------------------------------------


def test_start_up_ends_when_every_station_is_alive(system: Callable[..., System]) -> None:
    s = system()
    pids = {name: s.station(name, RUNS).process.pid for name in keys.STATIONS}
    s.up.heard.alive = set(keys.STATIONS)
    assert s.up.supervisor.wait_until_up(time.monotonic()) == ""
    for name, pid in pids.items():
        assert any(line.startswith(f"abyss:   {name} up (pid {pid}, ") for line in s.lines), s.output()


def test_start_up_fails_on_a_death_or_the_timeout_and_ends_on_an_interrupt(
    system: Callable[..., System], monkeypatch: pytest.MonkeyPatch
) -> None:
    s = system()
    for name in ("simulation", "vessel", "onshore"):
        s.station(name, RUNS)
    s.exited("onboard", 1)
    s.up.heard.alive = {"simulation"}
    assert s.up.supervisor.wait_until_up(time.monotonic()) == "onboard died during start-up"
    assert "abyss: station onboard died with exit code 1; log" in s.output()

    s = system()
    for name in keys.STATIONS:
        s.station(name, RUNS)
    s.up.interrupted.set()
    assert (
        s.up.supervisor.wait_until_up(time.monotonic()) == ""
    )  # not a failure: the verdict says interrupted

    monkeypatch.setattr(supervise_module, "STARTUP_TIMEOUT_S", 0.3)
    s = system()
    for name in keys.STATIONS:
        s.station(name, RUNS)
    s.up.heard.alive = {"simulation"}
    t0 = time.monotonic()
    assert s.up.supervisor.wait_until_up(t0) == "not up after 0.3 s: onboard, onshore, vessel"
    assert 0.3 <= time.monotonic() - t0 < 10.0


def test_the_watch_ends_with_the_mission_and_marks_it_done(system: Callable[..., System]) -> None:
    s = system()
    s.station("simulation", RUNS)
    s.up.heard.mission = mission(done=True)
    t0 = time.monotonic()
    assert s.up.supervisor.watch(duration_s=60.0, keep_running=False) == ""
    assert time.monotonic() - t0 < 30.0
    assert s.up.supervisor.mission_done_s is not None and "mission complete at t=" in s.output()
    state = RunState.read(s.up.out_dir)
    assert state is not None and state.mission_done


def test_the_watch_keeps_running_after_the_mission_until_the_duration(system: Callable[..., System]) -> None:
    s = system()
    s.up.heard.mission = mission(done=True)
    t0 = time.monotonic()
    assert s.up.supervisor.watch(duration_s=0.5, keep_running=True) == ""
    assert time.monotonic() - t0 >= 0.5
    assert s.output().count("mission complete") == 1  # said once, not on every pass


def test_the_watch_fails_when_a_station_dies_and_stops_when_interrupted(
    system: Callable[..., System],
) -> None:
    s = system()
    s.station("simulation", RUNS)
    s.exited("onboard", 2)
    s.up.heard.mission = mission(done=False)
    assert s.up.supervisor.watch(duration_s=60.0, keep_running=False) == "onboard died"

    s = system()
    s.station("simulation", RUNS)
    s.up.interrupted.set()
    assert s.up.supervisor.watch(duration_s=None, keep_running=True) == ""
    assert "abyss: interrupted; stopping the stations" in s.output()


# -- the summary -------------------------------------------------------------------------------


def status_file(name: str, system_id: str = "unit") -> dict[str, object]:
    """What `abyss station --status-file` writes, in short."""
    hop, other = {
        "simulation": ("rov", "onboard"),
        "onboard": ("tether", "vessel"),
        "vessel": ("satellite", "onshore"),
        "onshore": ("satellite", "vessel"),
    }[name]
    key = f"abyss/{system_id}/{name}/telemetry"
    return {
        "exit_code": 0,
        "sent": {key: 10},
        "received": {f"abyss/{system_id}/{other}/x": 4},
        "rejected": {key: 1},
        "latency_ms": {key: {"latency_p50_ms": 1.0}},
        "refused": {},
        "links": {
            hop: {
                "direction": f"{name}->{other}",
                "profile": hop,
                "messages_offered": 10.0,
                "messages_delivered": 9.0,
                "losses": 1.0,
                "retransmissions": 2.0,
                "delay_p50_ms": 100.0,
                "delay_p99_ms": 150.0,
            }
        },
        "scheduler": "fifo 10" if name == "simulation" else "normal (not asked for)",
        "about": {"physics": "c"} if name == "simulation" else {},
    }


def test_summary_of_a_station_that_died_without_its_status_file_is_failed(
    system: Callable[..., System],
) -> None:
    s = system(external=["onshore"])
    for name in ("simulation", "vessel"):
        station = s.exited(name, 0)
        station.status_path.write_text(json.dumps(status_file(name)))
    s.exited("onboard", 1)  # no status file: it never got to write one
    s.up.heard.alive_seen = {"simulation", "onboard", "vessel"}
    summary = s.up.summary(12.3456, 1.5, failure="")
    assert summary["verdict"] == "failed" and summary["failure"] == "a station exited with an error"
    onboard = summary["stations"]["onboard"]
    assert onboard["exit_code"] == 1 and onboard["alive_seen"]
    assert onboard["sent"] == onboard["received"] == onboard["rejected"] == onboard["latency_ms"] == {}
    assert summary["stations"]["onshore"] == {"external": True, "alive_seen": False}
    assert summary["stations"]["simulation"]["sent"] == {"abyss/unit/simulation/telemetry": 10}
    # each station's links, by hop and direction; the status file's own exit code is not used
    assert summary["links"]["rov"]["simulation->onboard"]["messages_delivered"] == 9.0
    assert summary["links"]["satellite"]["vessel->onshore"]["profile"] == "satellite"
    assert summary["links"]["tether"] == {} and set(summary["links"]) == set(keys.HOPS)
    assert summary["wall_s"] == 12.346 and summary["startup_s"] == 1.5
    assert summary["mission"] is None and summary["mission_done_s"] is None and summary["control"] is None
    assert summary["scene"] == {} and summary["external"] == ["onshore"]
    json.dumps(summary)  # summary.json

    text = render_summary(summary)
    assert text.splitlines()[0] == (
        "abyss: unit: failed (a station exited with an error); up in 1.5 s, ran 12 s"
    )
    assert "  onboard          1        0         0         0" in text
    assert "  onshore     external, never seen" in text
    assert "  rov simulation->onboard      emulated      9/10       100.0   150.0     1     2" in text
    assert "  mission: no status reached shore" in text
    # a netem hop's statistics are the kernel's: its drops are its losses (the first netem lab, in
    # UML, crashed here on a KeyError)
    netem = {"mode": "netem", "messages_delivered": 5.0, "messages_offered": 5.0, "netem_drops": 2.0}
    summary["links"]["satellite"]["vessel->onshore"] = netem
    assert (
        "  satellite vessel->onshore    netem         5/5          0.0     0.0     2     0"
        in render_summary(summary)
    )


def test_summary_keeps_the_failure_given_and_the_died_code(system: Callable[..., System]) -> None:
    s = system()
    for name in ("simulation", "vessel", "onshore"):
        s.exited(name, 0)
    killed = s.station("onboard", RUNS)
    killed.process.kill()
    killed.process.wait(timeout=60)
    s.up.supervisor.check_deaths()
    summary = s.up.summary(30.0, 1.0, failure="onboard died")
    assert summary["verdict"] == "failed" and summary["failure"] == "onboard died"
    assert summary["stations"]["onboard"]["exit_code"] == -signal.SIGKILL
    assert "onboard     -9 (SIGKILL)" in render_summary(summary)


def test_summary_of_a_clean_run_is_done(system: Callable[..., System]) -> None:
    s = system()
    for name in keys.STATIONS:
        s.exited(name, 0).status_path.write_text(json.dumps(status_file(name)))
    s.up.heard.mission = mission(done=True)
    s.up.supervisor.mission_done_s = 28.2
    s.up.heard.simulation = SimulationStatus(sim_time_s=29.5, realtime_factor=0.98, deadlines_met=0.995)
    summary = s.up.summary(31.0, 1.2, failure="")
    assert summary["verdict"] == "done" and summary["failure"] == ""
    assert summary["mission"]["done"] is True and summary["mission_done_s"] == 28.2
    text = render_summary(summary)
    assert text.splitlines()[0] == "abyss: unit: done; up in 1.2 s, ran 31 s"
    assert "  mission: reached, 3/3 waypoints, done: True" in text
    assert (
        "  simulation: 29.5 s simulated, real-time factor 0.98, deadlines met 99.5% (scheduler: fifo 10)"
    ) in text
    assert summary["stations"]["simulation"]["scheduler"] == "fifo 10"
    assert summary["stations"]["simulation"]["physics"] == "c"  # what the station said of itself
    assert "physics" not in summary["stations"]["vessel"]


def test_render_summary_of_every_section() -> None:
    summary = {
        "system": "demo",
        "verdict": "ok",
        "failure": "",
        "startup_s": 1.04,
        "wall_s": 30.4,
        "stations": {
            "simulation": {
                "exit_code": 0,
                "restarts": 2,
                "sent": {"a": 5, "b": 6},
                "received": {"c": 7},
                "rejected": {},
                "cpu": {
                    "cpu_s": 5.5,
                    "wall_s": 30.0,
                    "cores": 0.1833,
                    "cap_cores": 0.3,
                    "throttled_share": 0.61,
                },
                "shed": {"k1": 3, "k2": 4},
                "loops": {
                    "physics": {"period_s": 0.05, "ticks": 600, "deadlines_met": 0.987},
                    "cameras": {"period_s": 1.0, "ticks": 30, "deadlines_met": 1.0},
                },
            },
            "onboard": {"external": True, "alive_seen": True},
        },
        "links": {
            "satellite": {
                "vessel->onshore": {
                    "messages_delivered": 70.0,
                    "messages_offered": 71.0,
                    "delay_p50_ms": 239.1,
                    "delay_p99_ms": 1187.2,
                    "losses": 7.0,
                    "retransmissions": 12.0,
                }
            },
            "rov": {},
        },
        "mission": None,
        "control": {
            "position_error_m": 0.0055,
            "heading_error_deg": 0.04,
            "ee_position_error_m": 0.00329,
            "ee_orientation_error_deg": 0.07,
            "failsafe_events": 0,
        },
        "scene": {
            "occupied_cells": 16900,
            "resolution_m": 0.1,
            "updates_applied": 19,
            "update_bytes": 68_000,
            "gaps": 0,
            "objects": {"panel": {}, "valve_1": {}},
        },
        "simulation": {
            "sim_time_s": 18.8,
            "realtime_factor": 0.99,
            "deadlines_met": 0.995,
            "faults": {"thruster_2": 0.5},
        },
    }
    assert render_summary(summary).splitlines() == [
        "abyss: demo: ok; up in 1.0 s, ran 30 s",
        "  station       exit     sent  received  rejected  cores   shed        deadlines",
        "  simulation       0       11         7         0   0.18      7    98.7% physics  capped at 0.3 "
        "core, throttled in 61% of its periods  restarted 2x",
        "  onboard     external, seen",
        "  the stations' CPU: 0.18 cores in all (each station's process time over its wall time); shed: "
        "frames let go unprocessed for newer ones; deadlines: the station's worst loop",
        "  link                         mode         delivered  p50 ms  p99 ms  lost  retx",
        "  satellite vessel->onshore    emulated     70/71       239.1  1187.2     7    12",
        "  mission: no status reached shore",
        "  final errors (onboard): vehicle 5.5 mm, heading 0.04 deg; end-effector 3.29 mm, 0.07 deg; "
        "failsafe events 0",
        "  scene on shore: 16900 occupied cells at 0.1 m from 19 updates (68 kB), 0 gaps; "
        "recognised: panel, valve_1",
        "  simulation: 18.8 s simulated, real-time factor 0.99, deadlines met 99.5%, "
        "faults {'thruster_2': 0.5}",
    ]


@pytest.mark.parametrize(
    ("failure", "done", "interrupted", "keep_running", "verdict", "code"),
    [
        ("", True, False, False, "done", 0),
        ("", True, True, True, "done", 0),  # Ctrl-C ends a run kept running after its mission
        ("", False, False, False, "incomplete", 3),
        ("", False, False, True, "incomplete", 0),  # asked to run for its duration, not for a mission
        ("", False, True, False, "interrupted", 130),
        ("onboard died", True, False, False, "failed", 1),
        ("onboard did not stop within 10 s", False, True, True, "failed", 1),
    ],
)
def test_the_verdict_and_the_exit_code(
    failure: str, done: bool, interrupted: bool, keep_running: bool, verdict: str, code: int
) -> None:
    assert verdict_of(failure, done, interrupted) == verdict
    assert exit_code(verdict, keep_running) == code
