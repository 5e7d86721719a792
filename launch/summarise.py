"""`abyss up`'s summary of a run (`summary.json`): each station's exit, counts and links, the
restarts, the mission and its verdict, the run's time, from what the supervisor saw and what
each station left in its status file."""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Any

from abyss.common.runfiles import EVENTS_FILE, read_json_list
from abyss.config import Config, robot_of
from abyss.interface import keys
from abyss.launch.cpu import CpuCaps
from abyss.launch.observe import Heard
from abyss.launch.start import Station
from abyss.launch.supervise import Supervisor
from abyss.launch.verdict import HYBRID_JUDGE, control_summary, read_json, verdict_of

COUNTS = ("sent", "received", "rejected", "latency_ms", "cpu", "shed", "loops")  # from a status file


def station_summary(
    station: Station, alive_seen: bool, cpu: CpuCaps
) -> tuple[dict[str, Any], dict[str, Any]]:
    """A station's summary, and its links by hop (each a direction's figures)."""
    status = read_json(station.status_path)
    links = status.pop("links", {})
    code = station.died if station.died is not None else station.process.returncode
    summary = {
        "exit_code": code,
        "restarts": station.restarts,
        "stop_s": status.get("stop_s"),
        "stop_cut": status.get("stop_cut", False),
        "alive_seen": alive_seen,
        "log": str(station.log_path),
        **{k: status.get(k, {}) for k in COUNTS},
        "scheduler": status.get("scheduler", ""),
        **status.get("about", {}),  # the station's own facts (the simulation: its physics)
    }
    if station.name in cpu.caps:
        summary["cpu"] = {
            **summary["cpu"],
            "cap_cores": cpu.caps[station.name],
            "throttled_share": round(cpu.throttled_share.get(station.name, 0.0), 4),
        }
    return summary, links


def time_summary(config: Config, supervisor: Supervisor, heard: Heard) -> dict[str, Any]:
    """The run's time source and, with simulated time, the speed achieved and the station that
    held the simulation back the longest (`held_s`: wall seconds the simulation waited on each)."""
    summary: dict[str, Any] = {"mode": config.time.mode, "speed": config.time.speed}
    if supervisor.sim_clock is None or supervisor.watch_from is None:
        return summary
    sim_s = supervisor.now_s() - supervisor.watch_from[0]
    wall_s = time.monotonic() - supervisor.watch_from[1]
    held = dict(heard.simulation.held_s) if heard.simulation else {}
    speed = sim_s / wall_s if wall_s > 0 else 0.0
    if config.time.mode == "lockstep":
        limited_by = "each period's slowest station"  # the periods follow each other at once
    elif speed >= 0.95 * config.time.speed_factor:
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


def robot_summary(config: Config) -> dict[str, Any]:
    """The robot the run flew: its package and the names every station learnt from it."""
    robot = robot_of(config)
    return {
        "name": robot.name,
        "package": str(robot.directory),
        "model": str(robot.model_file),
        "arm_joints": list(robot.arm_joints),
        "gripper_joints": list(robot.gripper_joints),
        "thrusters": list(robot.thrusters),
        "cameras": list(robot.cameras),
        "sonar": robot.sonar_site if robot.has_sonar else None,
    }


def hybrid_summary(config: Config) -> dict[str, Any] | None:
    """A hybrid run: who provided each output of the simulation, the site's registration, and
    which verdicts the truth cannot give; None for an all-simulated run."""
    hybrid = config.hybrid
    if not hybrid.on:
        return None
    return {
        "providers": hybrid.providers(),
        "vehicle_via": "ros2" if config.ros2.station == "simulation" else "abyss keys",
        "site_origin_m_nav": list(hybrid.site_origin_m_nav),
        "site_heading_rad": hybrid.site_heading_rad,
        "unavailable": {
            "interventions": HYBRID_JUDGE,
            "navigation": "no truth to measure onboard's navigation against: the vehicle's is the only one",
        },
    }


@dataclasses.dataclass(frozen=True)
class Ending:
    """How the run ended, as the supervisor knows it once every station stopped."""

    wall_s: float
    startup_s: float
    failure: str
    interrupted: bool
    keep_running: bool


def run_summary(
    config: Config, endpoint: str, out_dir: Path, supervisor: Supervisor, cpu: CpuCaps, ending: Ending
) -> dict[str, Any]:
    """`summary.json`'s table."""
    heard = supervisor.heard
    stations: dict[str, Any] = {}
    links: dict[str, dict[str, Any]] = {hop: {} for hop in keys.HOPS}
    for name, station in supervisor.stations.items():
        stations[name], its_links = station_summary(station, name in heard.alive_seen, cpu)
        for hop, stats in its_links.items():
            links[hop][stats["direction"]] = stats
    for name in supervisor.external:
        stations[name] = {"external": True, "alive_seen": name in heard.alive_seen}
    failure = ending.failure
    if not failure and any(s.get("exit_code", 0) != 0 for s in stations.values()):
        failure = "a station exited with an error"
    return {
        "system": config.system,
        "endpoint": endpoint,
        "robot": robot_summary(config),
        "verdict": verdict_of(failure, supervisor.mission_done_s is not None, ending.interrupted),
        "failure": failure,
        "keep_running": ending.keep_running,
        "restarts": [outage.summary() for outage in supervisor.restarts],
        "startup_s": round(ending.startup_s, 3),
        "wall_s": round(ending.wall_s, 3),
        "stations": stations,
        "links": links,
        "mission": dataclasses.asdict(heard.mission) if heard.mission else None,
        "mission_done_s": supervisor.mission_done_s,
        "mission_done_wall_s": supervisor.mission_done_wall_s,
        "time": time_summary(config, supervisor, heard),
        "external": list(supervisor.external),
        "control": control_summary(heard.record.last if heard.record else None),
        "navigation": heard.nav_error.summary(),  # onboard's position error [m]
        "hybrid": hybrid_summary(config),
        "interventions": heard.interventions(config),
        "simulation": dataclasses.asdict(heard.simulation) if heard.simulation else None,
        "scene": read_json(out_dir / "scene.json"),
        "events": read_json_list(out_dir / EVENTS_FILE),  # the restarts as shore saw them
    }
