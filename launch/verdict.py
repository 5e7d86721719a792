"""A run's verdict and exit code, the figures it rests on (the controllers' final errors, each
intervention on the simulation's truth) and the screen of text `abyss up` ends with; `summarise`
puts them together with what the supervisor saw into `summary.json`."""

from __future__ import annotations

import json
import math
import signal
from pathlib import Path
from typing import Any

import numpy as np

from abyss.config.system import MissionConfig
from abyss.description.models.panel import Panel
from abyss.interface.messages import MissionStatus, PanelState, Telemetry
from abyss.launch.state import Verdict

VALVE_TOLERANCE_DEG = 5.0  # a valve turned within this of its target is turned
LEVER_TOLERANCE_DEG = 3.0  # a lever within this of its stop is at its stop

VERDICTS: dict[Verdict, int] = {  # the word, and what `abyss up` exits with
    "done": 0,  # shore saw the mission done, and nothing failed
    "incomplete": 3,  # the run reached its duration before the mission was done
    "interrupted": 130,  # Ctrl-C or SIGTERM before the mission was done (128 + SIGINT)
    "failed": 1,  # a station died and was not restarted, exited with an error or did not stop
}


def verdict_of(failure: str, mission_done: bool, interrupted: bool) -> Verdict:
    if failure:
        return "failed"
    if mission_done:
        return "done"
    return "interrupted" if interrupted else "incomplete"


def exit_code(verdict: Verdict, keep_running: bool) -> int:
    """A run asked to keep running for its duration is not judged on its mission: `incomplete`
    exits 0 there."""
    return 0 if verdict == "incomplete" and keep_running else VERDICTS[verdict]


def exit_text(code: int | None) -> str:
    if code is not None and code < 0:
        return f"{code} ({signal.Signals(-code).name})"
    return str(code)


def read_json(path: Path) -> dict[str, Any]:
    try:
        return dict(json.loads(path.read_text()))
    except (OSError, ValueError):
        return {}


def control_summary(t: Telemetry | None) -> dict[str, Any] | None:
    """The controllers' final state and errors, from the last telemetry onboard sent."""
    if t is None:
        return None
    return {
        "sim_time_s": t.sim_time_s,
        "mode": t.mode,
        "arm_mode": t.arm_mode,
        "position_error_m": t.position_error_m,
        "heading_error_deg": abs(math.degrees(t.heading_error_rad)),
        "ee_position_error_m": float(np.linalg.norm(t.ee_position_error_m_world)),
        "ee_orientation_error_deg": math.degrees(t.ee_orientation_error_rad),
        "failsafe": t.failsafe,
        "failsafe_events": t.failsafe_events,
    }


class NavError:
    """Onboard's navigation estimate (its telemetry's position) against the simulation's truth at
    the same simulated time, over the run. Thread-safe enough for Zenoh's callbacks: each side
    only appends, and a lookup misses at worst."""

    def __init__(self, keep: int = 400) -> None:
        self.truth: dict[float, np.ndarray] = {}  # sim time [s] -> position [m, world], the latest `keep`
        self.errors_m: list[float] = []
        self._keep = keep

    def add_truth(self, sim_time_s: float, position_m_world: np.ndarray) -> None:
        self.truth[round(sim_time_s, 6)] = position_m_world
        if len(self.truth) > self._keep:
            del self.truth[next(iter(self.truth))]

    def add_estimate(self, t: Telemetry) -> None:
        truth = self.truth.get(round(t.sim_time_s, 6))
        if truth is not None:
            self.errors_m.append(float(np.linalg.norm(t.position_m_world - truth)))

    def summary(self) -> dict[str, Any] | None:
        if not self.errors_m:
            return None
        return {
            "median_m": float(np.median(self.errors_m)),
            "max_m": max(self.errors_m),
            "samples": len(self.errors_m),
        }


def interventions_summary(
    mission: MissionConfig, panel: Panel, start: PanelState | None, last: PanelState | None
) -> list[dict[str, Any]]:
    """Each of the mission's interventions judged on the simulation's truth: the part's angle
    against its target (a valve: where it started plus the turn; a lever: its stop)."""
    judged = []
    angles_deg: dict[str, float] = {}  # each part as the interventions before left it to be
    for part, amount in mission.interventions:
        turn_rad, stop = panel.intent(part, amount)
        index = start.names.index(part) if start is not None and part in start.names else None
        started_deg = 0.0 if start is None or index is None else math.degrees(start.angles_rad[index])
        begin_deg = angles_deg.get(part, started_deg)
        low, high = panel.part_range_rad(part)
        target_deg = (
            math.degrees(high if stop == "up" else low) if stop else begin_deg + math.degrees(turn_rad)
        )
        angles_deg[part] = target_deg
        truth_deg = math.degrees(last.angles_rad[index]) if last is not None and index is not None else None
        tolerance_deg = LEVER_TOLERANCE_DEG if stop else VALVE_TOLERANCE_DEG
        judged.append(
            {
                "part": part,
                "target_deg": round(target_deg, 2),
                "tolerance_deg": tolerance_deg,
                "truth_deg": None if truth_deg is None else round(truth_deg, 2),
                "success": truth_deg is not None and abs(truth_deg - target_deg) <= tolerance_deg,
            }
        )
    return judged


HYBRID_JUDGE = (
    "unavailable: a hybrid run, whose truth is the real world; judged on shore by onboard's "
    "measurement and the vessel's vision"
)


def hybrid_interventions(mission: MissionConfig, status: MissionStatus | None) -> list[dict[str, Any]]:
    """A hybrid run's interventions: no truth judges them (success None); shore's mission status
    says which onboard reported done, by its own measurement of the part through the vessel's
    vision."""
    done = status.interventions_done if status is not None else 0
    return [
        {"part": part, "truth_deg": None, "success": None, "done_on_shore": i < done, "truth": HYBRID_JUDGE}
        for i, (part, _amount) in enumerate(mission.interventions)
    ]


def deadlines_text(loops: dict[str, dict[str, Any]]) -> str:
    """The share of deadlines met by a station's worst loop, and its name."""
    if not loops:
        return "-"
    name, worst = min(loops.items(), key=lambda item: item[1]["deadlines_met"])
    return f"{worst['deadlines_met']:.1%} {name}"


def render_summary(summary: dict[str, Any]) -> str:
    """The screen of text `abyss up` ends with, one section after the other."""
    sections = (
        _hybrid_lines,
        _stations_lines,
        _restart_lines,
        _link_lines,
        _mission_lines,
        _control_lines,
        _scene_lines,
        _simulation_lines,
        _time_lines,
    )
    lines = [
        f"abyss: {summary['system']}: {summary['verdict']}"
        + (f" ({summary['failure']})" if summary["failure"] else "")
        + f"; up in {summary['startup_s']:.1f} s, ran {summary['wall_s']:.0f} s"
    ]
    for section in sections:
        lines += section(summary)
    return "\n".join(lines)


def _station_line(name: str, s: dict[str, Any]) -> str:
    if s.get("external"):
        return f"  {name:<11} external, {'seen' if s['alive_seen'] else 'never seen'}"
    return (
        f"  {name:<11} {exit_text(s['exit_code']):>6} {sum(s['sent'].values()):>8} "
        f"{sum(s['received'].values()):>9} {sum(s['rejected'].values()):>9} "
        f"{s['cpu']['cores'] if s.get('cpu') else float('nan'):>6.2f} "
        f"{sum(s.get('shed', {}).values()):>6} {deadlines_text(s.get('loops', {})):>16}"
        + (
            f"  capped at {s['cpu']['cap_cores']:g} core, throttled in "
            f"{s['cpu']['throttled_share']:.0%} of its periods"
            if "cap_cores" in s.get("cpu", {})
            else ""
        )
        + (f"  restarted {s['restarts']}x" if s["restarts"] else "")
        + ("  its stop was cut at 5 s (stacks in its log)" if s.get("stop_cut") else "")
    )


def _hybrid_lines(summary: dict[str, Any]) -> list[str]:
    hybrid = summary.get("hybrid")
    if not hybrid:
        return []
    by = {who: [t for t, p in hybrid["providers"].items() if p == who] for who in ("vehicle", "twin")}
    twin = summary["stations"].get("simulation", {}).get("twin", {})
    delay = (
        f", {twin['nav_to_frame_p50_ms']:.0f} ms from navigation to frame (median)"
        if twin.get("frames")
        else ""
    )
    return [
        f"  hybrid: the real vehicle provided {', '.join(by['vehicle'])} ({hybrid['vehicle_via']}); the "
        f"twin rendered {', '.join(by['twin'])}: {twin.get('frames', 0)} sensor turns{delay}, "
        f"{twin.get('withheld', 0)} withheld (navigation missing or stale)",
        "  truth-based verdicts unavailable: the truth is the real world's",
    ]


def _stations_lines(summary: dict[str, Any]) -> list[str]:
    lines = [
        f"  {'station':<11} {'exit':>6} {'sent':>8} {'received':>9} {'rejected':>9} {'cores':>6} "
        f"{'shed':>6} {'deadlines':>16}"
    ]
    lines += [_station_line(name, s) for name, s in summary["stations"].items()]
    cores = [s["cpu"]["cores"] for s in summary["stations"].values() if s.get("cpu")]
    if cores:
        lines.append(
            f"  the stations' CPU: {sum(cores):.2f} cores in all (each station's process time "
            "over its wall time); shed: frames let go unprocessed for newer ones; deadlines: "
            "the station's worst loop"
        )
    return lines


def _restart_lines(summary: dict[str, Any]) -> list[str]:
    lines = []
    for r in summary.get("restarts", []):
        back = f"down {r['down_s']:.1f} s" if r.get("down_s") is not None else "not back"
        strayed = (
            "no truth to tell how far the vehicle strayed (a hybrid run)"
            if summary.get("hybrid")
            else f"the vehicle strayed {r['drift_m'] * 1e3:.0f} mm meanwhile"
        )
        lines.append(
            f"  restart: {r['station']} at t={r['t_s']:.1f} s (exit {exit_text(r['exit_code'])}), "
            f"{back}, {strayed}"
        )
    for e in summary.get("events", []):
        lines.append(f"  on shore: {e['station']} {e['event']} (sim t={e['sim_time_s']:.1f} s)")
    return lines


def _link_lines(summary: dict[str, Any]) -> list[str]:
    lines = [
        f"  {'link':<28} {'mode':<8} {'delivered':>13} {'p50 ms':>7} {'p99 ms':>7} {'lost':>5} {'retx':>5}"
    ]
    for hop, directions in summary["links"].items():
        for direction, st in directions.items():
            # with a shaper, delays and losses are its packets' (netem's: its drops); the kernel retransmits
            lines.append(
                f"  {hop + ' ' + direction:<28} {st.get('mode', 'emulated'):<8} "
                f"{int(st['messages_delivered']):>6}/{int(st['messages_offered']):<6} "
                f"{st.get('delay_p50_ms', 0.0):>7.1f} {st.get('delay_p99_ms', 0.0):>7.1f} "
                f"{int(st.get('losses', st.get('netem_drops', 0))):>5} "
                f"{int(st.get('retransmissions', 0)):>5}"
            )
    return lines


def _mission_lines(summary: dict[str, Any]) -> list[str]:
    m = summary["mission"]
    lines = [
        "  mission: "
        + (
            f"{m['mode']}, {m['waypoint_index']}/{m['waypoints_total']} waypoints, done: {m['done']}"
            if m
            else "no status reached shore"
        )
        + (
            f"; {m['intervention_target']} {m['intervention_phase']}: {m['intervention_reason']}"
            if m and m.get("intervention_reason")
            else ""
        )
    ]
    for i in summary.get("interventions", []):
        if "done_on_shore" in i:  # a hybrid run
            lines.append(
                f"  intervention: {i['part']} {'done' if i['done_on_shore'] else 'NOT DONE'} on shore; "
                f"the simulation's truth {i['truth']}"
            )
            continue
        truth = "no truth" if i["truth_deg"] is None else f"{i['truth_deg']:.1f} deg"
        lines.append(
            f"  intervention (simulation's truth): {i['part']} at {truth}, target "
            f"{i['target_deg']:.0f} +- {i['tolerance_deg']:g} deg: "
            f"{'success' if i['success'] else 'NOT DONE'}"
        )
    return lines


def _control_lines(summary: dict[str, Any]) -> list[str]:
    lines = []
    c = summary["control"]
    if c:
        lines.append(
            f"  final errors (onboard): vehicle {c['position_error_m'] * 1e3:.1f} mm, heading "
            f"{c['heading_error_deg']:.2f} deg; end-effector "
            f"{c['ee_position_error_m'] * 1e3:.2f} mm, "
            f"{c['ee_orientation_error_deg']:.2f} deg; failsafe events {c['failsafe_events']}"
        )
    nav = summary.get("navigation")
    if nav:
        lines.append(
            f"  navigation error (onboard's estimate against the truth): median "
            f"{nav['median_m'] * 1e3:.1f} mm, max {nav['max_m'] * 1e3:.1f} mm over {nav['samples']}"
        )
    return lines


def _scene_lines(summary: dict[str, Any]) -> list[str]:
    scene = summary["scene"]
    if not scene:
        return []
    lines = [
        f"  scene on shore: {scene['occupied_cells']} occupied cells at "
        f"{scene['resolution_m']:g} m "
        f"from {scene['updates_applied']} updates ({scene['update_bytes'] / 1e3:.0f} kB), "
        f"{scene['gaps']} gaps; recognised: {', '.join(scene['objects']) or 'nothing'}"
    ]
    p = scene.get("perception")
    if p:
        rates = ", ".join(f"{source} {r['mean']:.0f}" for source, r in p["points_per_s"].items())
        mapped = ", ".join(f"{source} {s:.0f} s" for source, s in p["scene_source_s"].items())
        lines.append(
            f"  perception (the vessel's, told shore): points/s {rates}; the scene from "
            f"{mapped or 'nothing'}; panel confidence {p['recognition_confidence']['last']:.2f} "
            f"(at most {p['recognition_confidence']['max']:.2f})"
        )
    return lines


def _simulation_lines(summary: dict[str, Any]) -> list[str]:
    sim = summary["simulation"]
    if not sim:
        return []
    scheduler = summary["stations"].get("simulation", {}).get("scheduler")
    return [
        f"  simulation: {sim['sim_time_s']:.1f} s simulated, real-time factor "
        f"{sim['realtime_factor']:.2f}, deadlines met {sim['deadlines_met']:.1%}"
        + (f" (scheduler: {scheduler})" if scheduler else "")
        + (f", faults {sim['faults']}" if sim["faults"] else "")
    ]


def _time_lines(summary: dict[str, Any]) -> list[str]:
    timing = summary.get("time", {})
    if "achieved_speed" not in timing:
        return []
    asked = f" at speed {timing['speed']}" if timing["mode"] == "sim" else ""
    return [
        f"  time: {timing['mode']}{asked}: {timing['sim_s']:.1f} s simulated in "
        f"{timing['wall_s']:.1f} s of wall time (x{timing['achieved_speed']:.2f}), limited by "
        f"{timing['limited_by']}"
    ]
