"""The assertions of a scenario, each a function of what the run left: the summary, onboard's
state over time (from its scoring key, so a link outage does not hide it) and the commands
shore sent. Each returns whether it held and the figure that says why."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from abyss.common.messages import Telemetry
from abyss.validation.scenario.spec import Assertion


@dataclass
class Run:
    summary: dict[str, Any]
    states: list[tuple[float, Telemetry]] = field(default_factory=list)  # (s since all up, state)
    commands: list[dict[str, Any]] = field(default_factory=list)
    killed: int = 0  # stations the scenario killed on purpose


@dataclass(frozen=True)
class Verdict:
    assertion: Assertion
    passed: bool
    detail: str


def mission_done(run: Run, within_s: float = math.inf) -> tuple[bool, str]:
    done_s = run.summary.get("mission_done_s")
    if done_s is None:
        mission = run.summary.get("mission") or {}
        return False, (
            f"not done: vehicle {mission.get('mode', 'no status')}, waypoint "
            f"{mission.get('waypoint_index', 0)}/{mission.get('waypoints_total', 0)}, arm "
            f"{mission.get('arm_mode', '-')}"
        )
    return done_s <= within_s, f"done at t={done_s:.1f} s (limit {within_s:g} s)"


def final_error(
    run: Run, vehicle_m: float = math.inf, ee_m: float = math.inf, ee_deg: float = math.inf
) -> tuple[bool, str]:
    c = run.summary.get("control")
    if not c:
        return False, "no controller state was recorded"
    held = (
        c["position_error_m"] <= vehicle_m
        and c["ee_position_error_m"] <= ee_m
        and (c["ee_orientation_error_deg"] <= ee_deg)
    )
    return held, (
        f"vehicle {c['position_error_m'] * 1e3:.1f} mm, end-effector {c['ee_position_error_m'] * 1e3:.1f}"
        f" mm, {c['ee_orientation_error_deg']:.2f} deg"
    )


def failsafe(
    run: Run, from_s: float, to_s: float, enter_within_s: float = 3.0, leave_within_s: float = 5.0
) -> tuple[bool, str]:
    """Entered within `enter_within_s` of `from_s`, and left within `leave_within_s` of `to_s`."""
    entered = next((t for t, s in run.states if t >= from_s and s.failsafe), None)
    if entered is None or entered - from_s > enter_within_s:
        return False, f"not entered within {enter_within_s:g} s of t={from_s:g} s"
    left = next((t for t, s in run.states if t >= max(to_s, entered) and not s.failsafe), None)
    if left is None or left - to_s > leave_within_s:
        return (
            False,
            f"entered after {entered - from_s:.1f} s, not left within {leave_within_s:g} s of t={to_s:g} s",
        )
    reason = next(s.failsafe for t, s in run.states if t >= entered and s.failsafe)
    return (
        True,
        f"entered {entered - from_s:.1f} s after t={from_s:g} s ({reason}), left {left - to_s:.1f} s after",
    )


def commands_answered(run: Run) -> tuple[bool, str]:
    lost = [f"{c['command']} {c['command_id']}" for c in run.commands if not c["answered"]]
    sends = sum(c["sends"] for c in run.commands)
    if not run.commands:
        return False, "shore sent no command"
    return not lost, (
        f"{len(run.commands)} commands, {sends} sends, all answered"
        if not lost
        else f"unanswered: {', '.join(lost)}"
    )


def scene(run: Run, min_occupied_cells: float = 1, objects: list[str] | None = None) -> tuple[bool, str]:
    s = run.summary.get("scene") or {}
    cells, seen = s.get("occupied_cells", 0), set(s.get("objects", {}))
    missing = sorted(set(objects or ()) - seen)
    return cells >= min_occupied_cells and not missing, (
        f"{cells} occupied cells on shore; recognised {', '.join(sorted(seen)) or 'nothing'}"
        + (f"; missing {', '.join(missing)}" if missing else "")
    )


def link(
    run: Run, hop: str, direction: str, stat: str, max: float = math.inf, min: float = -math.inf
) -> tuple[bool, str]:
    value = run.summary.get("links", {}).get(hop, {}).get(direction, {}).get(stat)
    if value is None:
        return False, f"no {stat} for {hop} {direction}"
    return min <= value <= max, f"{hop} {direction} {stat} = {value:g} (allowed [{min:g}, {max:g}])"


def stations(run: Run, max_restarts: float = 0, max_drift_m: float = math.inf) -> tuple[bool, str]:
    """No station failed; at most `max_restarts`, each station back up, and the vehicle never
    further than `max_drift_m` from where it was while a station was down."""
    own = {n: s for n, s in run.summary.get("stations", {}).items() if not s.get("external")}
    restarts = sum(s["restarts"] for s in own.values())
    failed = [n for n, s in own.items() if s["exit_code"] != 0]
    back = [r for r in run.summary.get("restarts", []) if r.get("down_s") is not None]
    drift_m = max((r["drift_m"] for r in back), default=0.0)
    ok = (run.summary.get("verdict") in ("done", "incomplete") and not failed and restarts <= max_restarts
          and len(back) == restarts and drift_m <= max_drift_m)
    return ok, (
        f"verdict {run.summary.get('verdict')}"
        + (f" ({run.summary['failure']})" if run.summary.get("failure") else "")
        + f", {restarts} restarts ({len(back)} back up), {run.killed} killed"
        + (f", the vehicle strayed at most {drift_m * 1e3:.0f} mm while a station was down" if back else "")
    )


def deadlines(run: Run, min_met: float) -> tuple[bool, str]:
    sim = run.summary.get("simulation") or {}
    met = sim.get("deadlines_met", 0.0)
    return met >= min_met, f"simulation deadlines met {met:.1%} (at least {min_met:.0%})"


CHECKS: dict[str, Callable[..., tuple[bool, str]]] = {
    "mission_done": mission_done,
    "final_error": final_error,
    "failsafe": failsafe,
    "commands_answered": commands_answered,
    "scene": scene,
    "link": link,
    "stations": stations,
    "deadlines": deadlines,
}


def judge(run: Run, assertions: tuple[Assertion, ...]) -> list[Verdict]:
    return [Verdict(a, *CHECKS[a.kind](run, **a.args)) for a in assertions]
