"""The vessel's cores, without Zenoh: the relay between onboard and shore, and what perception
works with. Each takes what came in and the time, and returns what to send (the scene stream's
core is `abyss.scene.stream.SceneStream`; the intake's, `intake.Intake`)."""

from __future__ import annotations

import dataclasses
import logging
import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from abyss.common.geometry import rotation_of
from abyss.config.stations import VesselConfig
from abyss.description.models.panel import Panel
from abyss.interface.messages import (
    CLOUD_SOURCES,
    IDLE_PHASES,
    PERCEPTION_SOURCES,
    CommandAck,
    Heartbeat,
    Intervention,
    InterventionGoal,
    Message,
    PerceptionStatus,
    RecognisedObjects,
    Telemetry,
)
from abyss.stations.vessel.intents import REFINE_M, part_angle_rad, resolve
from abyss.stations.vessel.recognition import seen_angles

RELAYED_DOWN = {
    "op/waypoints": "goal/waypoints",
    "op/arm": "goal/arm",
    "op/mode": "goal/mode",
    "op/intervene": "goal/intervene",
}
Outgoing = list[tuple[str, Message]]  # (topic, message) in the order to publish
log = logging.getLogger(__name__)
SEEN_MIN_CONFIDENCE = 0.5  # a part's angle measured with less is not believed
ARM_CLEAR_M = 0.3  # nor one with the tool nearer its pivot than this (a rebooted onboard's arm on it)


@dataclass
class RelayInputs:
    commands: list[tuple[str, Message]] = field(default_factory=list)  # (op/<topic>, command) from shore
    acks: list[CommandAck] = field(default_factory=list)  # onboard's answers
    shore_heard: bool = False  # a heartbeat of shore's came since the last step
    telemetry: tuple[int, Telemetry] | None = None  # onboard's latest, with its sequence number
    objects: RecognisedObjects | None = None  # what recognition found, the latest


class Relay:
    """Operator commands down as soon as they are seen, onboard's answers up, onboard's
    telemetry up at `telemetry_period_s`, and a heartbeat to onboard that says whether shore
    is heard. An intervention goes down resolved in the world frame (intents.resolve) once the
    panel is recognised by its markers (shore resends it meanwhile), or is refused here with the
    reason; as the panel's estimate moves (recognition sharpening as the vehicle closes in, the
    navigation's frame wandering), it goes down again resolved anew till it ends (onboard takes
    it as a refinement); the parts' angles are believed as the interventions onboard finished
    left them.

    Onboard rebooted mid-intervention is handed it again by shore (the same command): it is then
    resolved from where onboard last reported the part (the start of its run, plus its turn from
    the moment it held the part), toward the same target, an absolute angle; never again from the
    angle the part had before it was turned."""

    def __init__(self, cfg: VesselConfig, panel: Panel, now_s: float) -> None:
        self.cfg = cfg
        self.panel = panel
        self.shore_heard_s = now_s  # shore is given `shore_timeout_s` from the start
        self.last_beat_s = self.last_relay_s = -float("inf")
        self.forwarded_seq = -1
        self.objects: RecognisedObjects | None = None
        self.believed_rad: dict[str, float] = {}  # each part's angle, as the interventions left it
        self.resolved: dict[
            int, tuple[str, float]
        ] = {}  # command id: the part, its angle as onboard's run began
        self.target_rad: dict[int, float] = {}  # command id: the angle it turns the part to
        self.turned_rad: dict[
            int, float
        ] = {}  # command id: onboard's turn so far, from when it held the part
        self.boot_id: int | None = None  # onboard's, as its telemetry says
        self.refining: tuple[Intervention, InterventionGoal] | None = None  # the latest sent, till it ends

    def _placed(self) -> RecognisedObjects | None:
        """The panel's estimate if a frame that saw its markers made it: the markers place the parts
        along the panel's face (the shape alone slides along it, and a fit from the cloud alone can
        lie half a metre off, as a restarted vessel's first estimates do). A goal and each of its
        refinements wait for such an estimate: onboard would otherwise grasp beside the part."""
        return self.objects if self.objects is not None and "texture" in self.objects.method else None

    def _intervention(self, intent: Intervention) -> tuple[str, Message] | None:
        believed = self.believed_rad.get(intent.target, 0.0)
        again = intent.command_id in self.resolved
        start_rad = self.resolved.get(intent.command_id, (intent.target, believed))[1]
        target_rad = self.target_rad.setdefault(intent.command_id, start_rad + intent.turn_rad)
        intent = dataclasses.replace(intent, turn_rad=target_rad - start_rad)  # the target stays where it was
        goal, reason = resolve(self.panel, intent, self._placed(), start_rad, again)
        if goal is not None:
            self.resolved[intent.command_id] = (intent.target, start_rad)
            self.refining = intent, goal
            return "goal/intervene", goal
        return ("ack", CommandAck(intent.command_id, "intervene", reason)) if reason else None

    def _refined(self) -> tuple[str, Message] | None:
        """The intervention in hand resolved anew, when the panel's estimate has moved its grasp
        by REFINE_M or more, till it ends: onboard takes it whole until the fingers close, then
        the pivot's shift only (the panel moving in the navigation's frame)."""
        if self.refining is None:
            return None
        intent, sent = self.refining
        start_rad = self.resolved[intent.command_id][1]
        intent = dataclasses.replace(intent, turn_rad=self.target_rad[intent.command_id] - start_rad)
        goal, _ = resolve(self.panel, intent, self._placed(), start_rad, again=True)
        if goal is None or np.linalg.norm(goal.grasp_m_world - sent.grasp_m_world) < REFINE_M:
            return None
        self.refining = intent, goal
        return "goal/intervene", goal

    def _follow(self, t: Telemetry) -> None:
        """Onboard's turn of the part it works, from the moment it held it; on a reboot, its runs
        of the interventions begin anew where the parts were left."""
        if self.boot_id is not None and t.boot_id != self.boot_id:
            for command_id, turned_rad in self.turned_rad.items():
                target, start_rad = self.resolved[command_id]
                self.resolved[command_id] = (
                    target,
                    part_angle_rad(self.panel, target, start_rad + turned_rad),
                )
            self.turned_rad = {}
            self.refining = None  # handed again, it goes down resolved anew
        self.boot_id = t.boot_id
        self._adopt(t)
        if t.intervention_id in self.resolved and (
            t.intervention_phase == "turn" or t.intervention_id in self.turned_rad
        ):
            self.turned_rad[t.intervention_id] = t.turned_rad

    def _adopt(self, t: Telemetry) -> None:
        """An intervention onboard works that this vessel did not resolve (it restarted since):
        taken on from onboard's telemetry (its part and its turn), from where this vessel
        believes the part stood before it (what it saw of it, else at rest), so that onboard's
        turn is followed, the panel's estimate goes down as refinements, and a rebooted onboard
        is handed it again from where the part stands, not from that belief."""
        if t.intervention_id < 0 or t.intervention_id in self.resolved or t.intervention_phase in IDLE_PHASES:
            return
        lever = self.panel.part_kind(t.intervention_target) == "lever"
        stop = ("down" if t.turn_goal_rad < 0 else "up") if lever else ""
        intent = Intervention(
            t.intervention_id, t.intervention_target, 0.0 if lever else t.turn_goal_rad, stop
        )
        if not lever:  # the target it was given, held within the part's range from this belief
            believed = self.believed_rad.get(t.intervention_target, 0.0)
            self.target_rad[t.intervention_id] = part_angle_rad(
                self.panel, t.intervention_target, believed + t.turn_goal_rad
            )
        self._intervention(intent)  # what it would send is not sent: onboard has the goal
        if t.intervention_id in self.resolved:  # else it waits for the panel's markers
            log.info(
                "intervention %d on %s taken on from onboard's telemetry",
                t.intervention_id,
                t.intervention_target,
            )

    def _see(self, objects: RecognisedObjects, t: Telemetry | None) -> None:
        """The valves' angles as vision measures them (recognition.part_angles, within a degree
        at working distance), for the parts no intervention is working: a bar at a and at a + 180
        deg is one, taken nearest the belief. The levers' angles are seen to some 10 deg from in
        front (their throw is along the line of sight): not believed."""
        working = {self.refining[0].target} if self.refining is not None else set()
        if t is not None and t.intervention_phase not in IDLE_PHASES:
            working.add(t.intervention_target)
        panel_pose = objects.poses_world[objects.names.index("panel")]
        for name, seen in seen_angles(self.panel, objects).items():
            if (
                self.panel.part_kind(name) != "valve"
                or name in working
                or seen.confidence < SEEN_MIN_CONFIDENCE
            ):
                continue
            pivot_m_world = rotation_of(panel_pose[3:]) @ np.asarray(self.panel.valves[name]) + panel_pose[:3]
            if t is not None and np.linalg.norm(t.ee_position_m_world - pivot_m_world) < ARM_CLEAR_M:
                continue  # the tool is at it: the arm hides the bar, or holds it still
            believed = self.believed_rad.get(name, 0.0)
            lo, hi = self.panel.valve.range_rad
            candidates = [
                a for a in (seen.angle_rad + k * math.pi for k in (-1, 0, 1)) if lo - 0.1 < a < hi + 0.1
            ]
            self.believed_rad[name] = part_angle_rad(
                self.panel, name, min(candidates, key=lambda a: abs(a - believed))
            )
            if abs(self.believed_rad[name] - believed) > math.radians(1.0):
                log.info(
                    "%s seen at %.1f deg (believed %.1f before), confidence %.2f, the tool %s m off",
                    name,
                    math.degrees(self.believed_rad[name]),
                    math.degrees(believed),
                    seen.confidence,
                    "?" if t is None else f"{np.linalg.norm(t.ee_position_m_world - pivot_m_world):.2f}",
                )

    def _believe(self, t: Telemetry) -> None:
        if t.intervention_phase in ("done", "failed") and t.intervention_id in self.resolved:
            target, start_rad = self.resolved[t.intervention_id]
            self.believed_rad[target] = part_angle_rad(self.panel, target, start_rad + t.turned_rad)
            if self.refining is not None and self.refining[0].command_id == t.intervention_id:
                self.refining = None

    def step(self, inputs: RelayInputs, now_s: float) -> Outgoing:
        out: Outgoing = []
        state = inputs.telemetry[1] if inputs.telemetry is not None else None
        if state is not None:
            self._follow(state)
            self._believe(state)
        if inputs.objects is not None and inputs.objects is not self.objects:
            self.objects = inputs.objects
            self._see(inputs.objects, state)
            refined = self._refined()
            out += [refined] if refined else []
        for topic, command in inputs.commands:
            if isinstance(command, Intervention):
                resolved = self._intervention(command)
                out += [resolved] if resolved else []
            else:
                out.append((RELAYED_DOWN[topic], command))
        for ack in inputs.acks:
            out.append(("ack", ack))
            refused = ack.command == "intervene" and not ack.accepted
            if refused and self.refining is not None and self.refining[0].command_id == ack.command_id:
                # not taken (onboard busy with another): its refinements would be resends, and one
                # onboard judged again once free would work the part twice (a restarted shore's
                # intent, refused while onboard turned the part for the shore before it)
                self.refining = None
        if inputs.shore_heard:
            self.shore_heard_s = now_s
        if now_s - self.last_beat_s >= self.cfg.heartbeat_period_s:
            silence_s = now_s - self.shore_heard_s
            out.append(("heartbeat", Heartbeat(silence_s, silence_s < self.cfg.shore_timeout_s)))
            self.last_beat_s = now_s
        due = now_s - self.last_relay_s >= self.cfg.telemetry_period_s
        if due and inputs.telemetry is not None and inputs.telemetry[0] != self.forwarded_seq:
            out.append(("telemetry", inputs.telemetry[1]))
            self.forwarded_seq, self.last_relay_s = inputs.telemetry[0], now_s
        return out


class Perception:
    """What perception works with: the points each source brought over the last `window_s`, and
    which feeds the scene model. The cameras' clouds do; the sonar's echoes take over while the
    cameras' clouds bring no point for `fallback_s` (murk, failed cameras; from the first
    message of any source too, until the first cloud with points), and hand back at the first
    that does. Counted from the first message, not from the vessel's start: a vessel started
    long before the vehicle (a replay, a station started by hand) must not map from the first
    pings what the cameras would have."""

    def __init__(self, cfg: VesselConfig) -> None:
        self.window_s, self.fallback_s = cfg.perception_window_s, cfg.sonar_fallback_s
        self.started_s: float | None = None  # when the first message came
        self.cameras_seen_s = -float("inf")  # the last camera cloud with points
        self.sonar_seen = False
        self._points: deque[tuple[float, str, int]] = deque()  # (when, source, points)

    def received(self, source: str, points: int, now_s: float) -> None:
        self.started_s = now_s if self.started_s is None else self.started_s
        self._points.append((now_s, source, points))
        while self._points and self._points[0][0] < now_s - self.window_s:
            self._points.popleft()
        if source in CLOUD_SOURCES and points > 0:
            self.cameras_seen_s = now_s
        self.sonar_seen |= source == "sonar"

    def _started(self, now_s: float) -> float:
        return now_s if self.started_s is None else self.started_s

    def sonar_feeds(self, now_s: float) -> bool:
        return now_s - max(self.cameras_seen_s, self._started(now_s)) >= self.fallback_s

    def scene_source(self, now_s: float) -> str:
        if self.sonar_feeds(now_s):
            return "sonar" if self.sonar_seen else ""
        return "cameras" if self.cameras_seen_s > -float("inf") else ""

    def status(
        self, now_s: float, objects: RecognisedObjects | None, sim_time_s: float, backlog_cells: int
    ) -> PerceptionStatus:
        """What perception works with; `backlog_cells`: the scene model's cells queued for shore."""
        window_s = min(self.window_s, max(now_s - self._started(now_s), 1e-3))
        counts = dict.fromkeys(PERCEPTION_SOURCES, 0)
        for when, source, points in self._points:
            if when >= now_s - window_s:
                counts[source] += points
        confidence, method = 0.0, ""
        if objects is not None and "panel" in objects.names:
            confidence, method = float(objects.confidences[objects.names.index("panel")]), objects.method
        return PerceptionStatus(
            points_per_s={source: count / window_s for source, count in counts.items()},
            window_s=max(window_s, 0.1),
            scene_source=self.scene_source(now_s),
            recognition_confidence=confidence,
            recognition_method=method,
            sim_time_s=sim_time_s,
            scene_backlog_cells=backlog_cells,
        )
