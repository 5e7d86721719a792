"""The assertions of a scenario, each a function of what the run left: the summary, onboard's
state over time (from its scoring key, so a link outage does not hide it) and the commands
shore sent. Each returns whether it held and the figure that says why. A check's keyword
parameters, with their type hints and defaults, are its `[[assert]]` table's fields; `CHECKS`
registers each by its `kind`, so adding one is a function and a line there."""

from __future__ import annotations

import dataclasses
import functools
import inspect
import math
import re
import typing
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Annotated, Any, Literal

import numpy as np

from abyss.common.errors import ConfigError
from abyss.common.reading import OneOf
from abyss.description.robot import Robot, robot_at, robot_spec
from abyss.description.site import shipped_sites
from abyss.interface import keys
from abyss.interface.messages import INTERVENTION_PHASES, PERCEPTION_SOURCES, Telemetry

Outcome = Literal["done", "failed"]  # of an intervention
OUTCOMES: tuple[Outcome, ...] = typing.get_args(Outcome)
Station = Annotated[str, OneOf(keys.STATIONS)]
Phase = Annotated[str, OneOf(INTERVENTION_PHASES[1:], blank=True)]  # "": from all up


MISSION_PART = re.compile(r"^#(\d+)$")  # "#i": the part of the mission's i-th intervention


class PanelPart:
    """A rule: the name of a part of a shipped site's panel (description.site; a user's site's parts
    are the run's configuration's to check, its mission's interventions), or "#i": the part of
    the mission's i-th intervention (from 0), whatever the site names it, so that a scenario
    runs on any robot and site."""

    def check(self, name: str, value: Any) -> None:
        parts = {part for site in shipped_sites() for part in site.panel.part_names}
        if value not in parts and not MISSION_PART.match(str(value)):
            raise ConfigError(
                name,
                f"{value!r} is neither #i (the mission's i-th intervention's part) nor a part of a "
                f"shipped site's panel: {', '.join(sorted(parts))}",
            )


def part_named(run: Run, part: str) -> str:
    """The part a scenario's `part` names: itself, or for "#i" the mission's i-th intervention's
    (as the summary judged them); "" for an i past the mission's."""
    m = MISSION_PART.match(part)
    if m is None:
        return part
    judged = run.summary.get("interventions", [])
    return judged[int(m[1])]["part"] if int(m[1]) < len(judged) else ""


@dataclass(frozen=True)
class Assertion:
    kind: str
    args: dict[str, Any]  # the fields its table gives, as read

    def describe(self) -> str:
        return self.kind + "".join(f" {k}={v}" for k, v in self.args.items())


@dataclass
class Run:
    summary: dict[str, Any]
    states: list[tuple[float, Telemetry]] = field(default_factory=list)  # (s since all up, state)
    commands: list[dict[str, Any]] = field(default_factory=list)
    killed: int = 0  # stations the scenario killed on purpose
    robot: str = ""  # the robot package the run flew (simulation.robot; "" the shipped one)


@dataclass(frozen=True)
class Verdict:
    assertion: Assertion
    passed: bool
    detail: str

    def __str__(self) -> str:
        """The assertion, whether it held, and its figure."""
        return f"{self.assertion.describe()} {'held' if self.passed else 'failed'}: {self.detail}"


def phase_began_s(states: list[tuple[float, Telemetry]], phase: str) -> float | None:
    """When onboard first reported the intervention `phase` [s since all up]; 0 for no phase."""
    if not phase:
        return 0.0
    return next((t for t, s in states if s.intervention_phase == phase), None)


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
    run: Run,
    from_s: float,
    to_s: float,
    enter_within_s: float = 3.0,
    leave_within_s: float = 5.0,
    phase: Phase = "",
) -> tuple[bool, str]:
    """Entered within `enter_within_s` of `from_s`, and left within `leave_within_s` of `to_s`;
    both counted from when onboard first reported the intervention `phase`, if one is named."""
    origin_s = phase_began_s(run.states, phase)
    if origin_s is None:
        return False, f"onboard never reported the intervention phase {phase}"
    from_s, to_s = from_s + origin_s, to_s + origin_s
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
    """At least `min_occupied_cells` in shore's map, and each of `objects` recognised (an object's
    name, or "#i": the mission's i-th intervention's part)."""
    s = run.summary.get("scene") or {}
    cells, seen = s.get("occupied_cells", 0), set(s.get("objects", {}))
    missing = sorted({part_named(run, name) or name for name in objects or ()} - seen)
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
    ok = (
        run.summary.get("verdict") in ("done", "incomplete")
        and not failed
        and restarts <= max_restarts
        and len(back) == restarts
        and drift_m <= max_drift_m
    )
    return ok, (
        f"verdict {run.summary.get('verdict')}"
        + (f" ({run.summary['failure']})" if run.summary.get("failure") else "")
        + f", {restarts} restarts ({len(back)} back up), {run.killed} killed"
        + (f", the vehicle strayed at most {drift_m * 1e3:.0f} mm while a station was down" if back else "")
    )


def intervention(
    run: Run, part: Annotated[str, PanelPart()], outcome: Outcome = "done", reason: str = ""
) -> tuple[bool, str]:
    """The intervention on `part` ended `outcome` as onboard reported it, with `reason` in its
    reason (a failure's), and the simulation's truth agrees: the part at its target when done,
    short of it when failed."""
    asked, part = part, part_named(run, part)
    if not part:
        return False, f"{asked}: the mission has no such intervention"
    ends = [s for _, s in run.states if s.intervention_target == part and s.intervention_phase in OUTCOMES]
    if not ends:
        seen = [s.intervention_phase for _, s in run.states if s.intervention_target == part]
        return False, f"{part}: no end reported (last phase: {seen[-1] if seen else 'none'})"
    end = ends[-1]
    judged = next((i for i in run.summary.get("interventions", []) if i["part"] == part), None)
    truth = (
        "no truth"
        if judged is None
        else f"truth {judged['truth_deg']} deg, target {judged['target_deg']} deg"
    )
    on_target = judged is not None and judged["success"]
    held = (
        end.intervention_phase == outcome
        and reason in end.intervention_reason
        and on_target == (outcome == "done")
    )
    said = f": {end.intervention_reason}" if end.intervention_reason else ""
    return held, f"{part} {end.intervention_phase}{said}; {truth}"


def arm_limits(run: Run, margin_deg: float = 1.0) -> tuple[bool, str]:
    """No arm joint past its limit (the model's range, give or take `margin_deg`: MuJoCo's limits
    are soft) in any of onboard's states."""
    if not run.states:
        return False, "no onboard state was recorded"
    robot = robot_at(run.robot)
    low_rad, high_rad = arm_ranges_rad(robot)
    margin_rad = math.radians(margin_deg)
    q = np.array([s.arm_positions_rad for _, s in run.states])
    past_rad = np.maximum(low_rad - q, q - high_rad).max(axis=0)
    worst = int(np.argmax(past_rad))
    return bool(past_rad.max() <= margin_rad), (
        f"{len(q)} states; nearest a limit: {robot.arm_joints[worst]} at "
        f"{math.degrees(past_rad[worst]):+.1f} deg from it (allowed {margin_deg:g} deg past)"
    )


def arm_ranges_rad(robot: Robot) -> tuple[np.ndarray, np.ndarray]:
    """The arm's joint ranges [rad] as the robot's model (MuJoCo) has them, lower and upper."""

    model = robot_spec(robot).compile()
    ranges = np.array([model.jnt_range[model.joint(name).id] for name in robot.arm_joints])
    return ranges[:, 0], ranges[:, 1]


def deadlines(run: Run, min_met: float, station: Station = "simulation", loop: str = "") -> tuple[bool, str]:
    """A station's `loop` (else its worst) kept at least `min_met` of its deadlines."""
    loops = run.summary.get("stations", {}).get(station, {}).get("loops") or {}
    if loop:
        loops = {loop: loops[loop]} if loop in loops else {}
    if not loops:
        return False, f"{station} reported no loop {loop or ''}".rstrip()
    name, worst = min(loops.items(), key=lambda item: item[1]["deadlines_met"])
    met = worst["deadlines_met"]
    return met >= min_met, f"{station} {name} deadlines met {met:.1%} (at least {min_met:.0%})"


def shed(run: Run, station: Station, min: float = 0, max: float = math.inf) -> tuple[bool, str]:
    """The frames `station` let go unprocessed for newer ones, within [min, max]."""
    count = sum((run.summary.get("stations", {}).get(station, {}).get("shed") or {}).values())
    return min <= count <= max, f"{station} shed {count} frames (allowed [{min:g}, {max:g}])"


def _perception(run: Run) -> dict[str, Any]:
    """What shore was told of the vessel's perception (onshore.core.PerceptionSeen)."""
    return dict((run.summary.get("scene") or {}).get("perception") or {})


def perception(
    run: Run,
    source: Annotated[str, OneOf(PERCEPTION_SOURCES)],
    min_points_per_s: float = -math.inf,
    max_points_per_s: float = math.inf,
    min_mapped_s: float = 0.0,
) -> tuple[bool, str]:
    """The points `source` brought (its mean rate over shore's reports) within the bounds, and
    the scene mapped from it (the cameras', for depth and stereo) for at least `min_mapped_s`."""
    p = _perception(run)
    if not p:
        return False, "shore was told nothing of the vessel's perception"
    rate = p["points_per_s"].get(source, {}).get("mean")
    mapped_s = p["scene_source_s"].get("sonar" if source == "sonar" else "cameras", 0.0)
    if rate is None:
        return False, f"no report of {source} ({p['reports']} reports)"
    held = min_points_per_s <= rate <= max_points_per_s and mapped_s >= min_mapped_s
    return held, (
        f"{source}: {rate:.0f} points/s on average (allowed [{min_points_per_s:g}, "
        f"{max_points_per_s:g}]), the scene mapped from it for {mapped_s:.0f} s (at least "
        f"{min_mapped_s:g}); {p['reports']} reports on shore"
    )


def recognition(run: Run, min_confidence: float = 0.0, max_confidence: float = 1.0) -> tuple[bool, str]:
    """The panel's recognition confidence shore was last told within the bounds."""
    p = _perception(run)
    if not p:
        return False, "shore was told nothing of the vessel's perception"
    confidence = p["recognition_confidence"]
    return min_confidence <= confidence["last"] <= max_confidence, (
        f"panel confidence {confidence['last']:.2f} at the end (allowed [{min_confidence:g}, "
        f"{max_confidence:g}]), {confidence['max']:.2f} at most, by {p['recognition_method'] or 'nothing'}"
    )


CHECKS: dict[str, Callable[..., tuple[bool, str]]] = {
    "mission_done": mission_done,
    "final_error": final_error,
    "failsafe": failsafe,
    "commands_answered": commands_answered,
    "scene": scene,
    "link": link,
    "stations": stations,
    "deadlines": deadlines,
    "shed": shed,
    "intervention": intervention,
    "arm_limits": arm_limits,
    "perception": perception,
    "recognition": recognition,
}


@functools.cache
def fields_of(check: Callable[..., tuple[bool, str]]) -> type:
    """The frozen dataclass of a check's table: its parameters after `run`, with their type
    hints and defaults (what common.reading reads a table into)."""
    hints = typing.get_type_hints(check, include_extras=True)
    parameters = list(inspect.signature(check).parameters.values())[1:]
    return dataclasses.make_dataclass(
        f"{check.__name__}_fields",
        [
            (p.name, hints[p.name], dataclasses.field(default=p.default))
            if p.default is not inspect.Parameter.empty
            else (p.name, hints[p.name])
            for p in parameters
        ],
        frozen=True,
    )


def judge(run: Run, assertions: tuple[Assertion, ...]) -> list[Verdict]:
    return [Verdict(a, *CHECKS[a.kind](run, **a.args)) for a in assertions]
