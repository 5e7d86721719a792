"""The operator's core on shore, without Zenoh: the mission's commands (auto mode, waypoints,
then an end-effector goal) and whatever the operator's tools hand in, each resent over the
lossy satellite until onboard's answer comes back (an arm goal or an intervention after the
waypoints' answer: onboard judges it where the vehicle will hold, and links reorder what is sent
together); every command's fate; a heartbeat to the vessel; the mission status as the operator
sees it.

Shore joins the mission it finds: it sends the mission's commands once onboard's first telemetry
shows onboard has none (or after `JOIN_WAIT_S` without telemetry); a restarted shore that finds
onboard flying takes the commands in force as its own instead of starting over. When onboard
reboots (a new `boot_id` in its telemetry), shore hands it the goals in force again: the
waypoints not yet reached, the end-effector goal, the mode. Each is an event (`events`)."""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Any, Generic, TypeVar

import numpy as np

from abyss.config.system import MissionConfig
from abyss.description.models.panel import intent_of
from abyss.interface.messages import (
    IDLE_PHASES,
    ArmGoal,
    CommandAck,
    Heartbeat,
    Intervention,
    Message,
    MissionStatus,
    OperatorMode,
    PerceptionStatus,
    Telemetry,
    Waypoints,
    new_id,
)

HEARTBEAT_PERIOD_S = 1.0
STATUS_PERIOD_S = 0.25
JOIN_WAIT_S = 5.0  # how long a starting shore listens for onboard's state before it sends the mission
log = logging.getLogger(__name__)


C = TypeVar("C", Waypoints, ArmGoal, OperatorMode, Intervention)


@dataclass
class Command(Generic[C]):
    """The latest command on one op key, resent until onboard answers it."""

    topic: str
    message: C | None = None
    answer: CommandAck | None = None
    sent_s: float = -float("inf")
    after: Command[Waypoints] | None = None  # a command it waits for the answer to before it goes

    def waiting(self) -> bool:
        """It waits for `after`'s answer (links reorder what is sent together)."""
        return self.after is not None and self.after.message is not None and self.after.answer is None

    def replace(self, message: C) -> None:
        self.message, self.answer, self.sent_s = message, None, -float("inf")

    def again(self) -> None:
        """Hand the command in force again (onboard rebooted): unanswered, to be sent."""
        if self.message is not None:
            self.answer, self.sent_s = None, -float("inf")

    def in_force(self, message: C, now_s: float) -> None:
        """Take a command onboard already flies (found in its telemetry) as this one: answered,
        not to be sent."""
        self.message, self.sent_s = message, now_s
        self.answer = CommandAck(message.command_id, self.topic.removeprefix("op/"), "")

    def answered(self, ack: CommandAck) -> bool:
        """Take onboard's answer if it is to this command."""
        if self.message is None or self.message.command_id != ack.command_id or self.answer is not None:
            return False
        self.answer = ack
        return True


@dataclass
class OperatorInputs:
    tool_commands: list[tuple[str, Message]] = field(default_factory=list)  # (op/<topic>, command)
    acks: list[CommandAck] = field(default_factory=list)  # onboard's answers, through the vessel
    telemetry: list[Telemetry] = field(default_factory=list)


@dataclass
class OperatorOutputs:
    messages: list[tuple[str, Message]] = field(default_factory=list)  # over the satellite
    answers: list[CommandAck] = field(default_factory=list)  # for the tools
    first_sent: list[Message] = field(default_factory=list)  # commands sent for the first time
    status: MissionStatus | None = None  # when one is due


class Operator:
    def __init__(
        self,
        mission: MissionConfig,
        history: list[dict[str, object]] | None = None,
        events: list[dict[str, object]] | None = None,
        ground_station: bool = False,
    ) -> None:
        """`history` and `events`: what an earlier run of this station left (a restart).
        `ground_station`: the mission is a MAVLink ground station's (mavlink.enabled): shore sends
        none of its own (a tool's commands still go) and judges the one onboard flies."""
        self.mission = mission
        self.ground_station = ground_station
        self.mode: Command[OperatorMode] = Command("op/mode")
        self.mission_waypoints_m = np.array(mission.waypoints)  # [m, world]
        self.waypoints: Command[Waypoints] = Command("op/waypoints")
        # onboard judges an arm goal or an intervention where the vehicle will hold: the waypoints first
        self.arm: Command[ArmGoal] = Command("op/arm", after=self.waypoints)
        self.intervene: Command[Intervention] = Command("op/intervene", after=self.waypoints)
        self.intervention_index = 0  # of the mission's interventions, the one in hand
        goal = mission.arm_goal()
        if not ground_station:
            self.mode.replace(OperatorMode(new_id(), "auto"))
            self.waypoints.replace(Waypoints(new_id(), self.mission_waypoints_m))
            if goal is not None:
                self.arm.replace(ArmGoal(new_id(), *goal))
            if mission.interventions:
                self.intervene.replace(mission_intervention(mission, 0))
        self.commands: dict[str, Command[Any]] = {
            c.topic: c for c in (self.mode, self.waypoints, self.arm, self.intervene)
        }
        self.history: dict[tuple[str, int], dict[str, object]] = {  # every command sent, and its fate
            (f"op/{e['command']}", int(e["command_id"])): e  # type: ignore[call-overload]
            for e in history or []
        }
        self.events: list[dict[str, object]] = list(events or [])  # restarts seen, what shore did
        self.status: MissionStatus | None = None
        self.last_status_s = self.last_beat_s = -float("inf")
        self.first_step_s: float | None = None
        self.joined = False  # the mission's commands are released (sent, or found in force)
        self.onboard: Telemetry | None = None  # the latest telemetry of onboard's current boot
        self.waypoint_offset = 0  # mission waypoints reached before the list in force began

    def event(self, station: str, what: str) -> None:
        """Something shore saw of a station (a restart), at the simulated time of its latest telemetry."""
        log.info("%s: %s", station, what)
        sim_time_s = self.onboard.sim_time_s if self.onboard else 0.0
        self.events.append({"station": station, "event": what, "sim_time_s": round(sim_time_s, 3)})

    def _join(self, t: Telemetry, now_s: float) -> None:
        """Onboard's first telemetry: start the mission, or take the one it flies (shore restarted)."""
        self.joined = True
        if t.command_id < 0 or self.ground_station:
            return
        sent = self.waypoints.message  # the mission's, or a tool's that came before onboard's state
        mission = sent.waypoints if sent is not None else self.mission_waypoints_m
        total = t.waypoints_total if 0 < t.waypoints_total <= len(mission) else len(mission)
        self.waypoint_offset = len(mission) - total
        self.waypoints.in_force(Waypoints(t.command_id, mission[self.waypoint_offset :]), now_s)
        goal = self.mission.arm_goal()
        if goal is not None and t.arm_command_id >= 0:
            self.arm.in_force(ArmGoal(t.arm_command_id, *goal), now_s)
        self.mode.in_force(OperatorMode(new_id(), t.operator_mode), now_s)
        targets = [part for part, _ in self.mission.interventions]
        if t.intervention_id >= 0 and t.intervention_target in targets:  # the one onboard works on
            self.intervention_index = targets.index(t.intervention_target)
            self.intervene.in_force(
                mission_intervention(self.mission, self.intervention_index, t.intervention_id), now_s
            )
        for command in (self.waypoints, self.arm, self.intervene):
            entry = self.history.get((command.topic, command.message.command_id)) if command.message else None
            if entry is not None:  # sent by this station before its restart, flown since
                entry.update(answered=True, accepted=True)
        index = self.waypoint_offset + t.waypoint_index
        self.onboard = t
        self.event(
            "onshore", f"rejoined the mission in progress (waypoint {index}/{len(mission)}, arm {t.arm_mode})"
        )

    def _rehand(self, before: Telemetry | None, t: Telemetry) -> None:
        """Onboard rebooted: the goals in force again, the waypoints from the one it was flying."""
        flown = self.waypoints.message
        if flown is None:  # never: the waypoints are the mission's from the start
            return
        reached = 0
        if before is not None and before.command_id == flown.command_id:
            reached = min(before.waypoint_index, len(flown.waypoints) - 1)
        if reached:
            self.waypoint_offset += reached
            self.waypoints.replace(Waypoints(new_id(), flown.waypoints[reached:]))
        else:
            self.waypoints.replace(flown)
        for command in (self.arm, self.mode, self.intervene):
            command.again()
        self.onboard = t
        self.event("onboard", f"restarted: goals handed again from waypoint {self.waypoint_offset}")

    def _telemetry(self, t: Telemetry, now_s: float) -> None:
        if not self.joined:
            self._join(t, now_s)
        elif self.onboard is not None and t.boot_id != self.onboard.boot_id:
            self._rehand(self.onboard, t)
        self.onboard = t
        if self.ground_station:
            self.status = flown_status(t, self.mission.done_position_tolerance_m)
            return
        self._take_onboards(t, now_s)
        self._next_intervention(t)
        self.status = mission_status(
            t,
            self.waypoints,
            self.arm,
            self.waypoint_offset,
            self.intervene,
            self.intervention_index,
            len(self.mission.interventions),
            self.mission.done_position_tolerance_m,
        )

    def _take_onboards(self, t: Telemetry, now_s: float) -> None:
        """Onboard works the mission's part in hand under another command, and refused this
        station's as it did: the command a shore sent before its restart, begun after the restarted
        shore joined from older telemetry. That command is taken as this one (in force), so the
        mission follows onboard's run of it to its end rather than waiting on a refused one."""
        current, answer = self.intervene.message, self.intervene.answer
        if (
            current is None
            or answer is None
            or answer.accepted  # only a refused one is replaced
            or t.intervention_id < 0
            or t.intervention_id == current.command_id
            or t.intervention_target != current.target
            or t.intervention_phase in IDLE_PHASES  # one that ended is no answer to a refusal
        ):
            return
        taken = mission_intervention(self.mission, self.intervention_index, t.intervention_id)
        self.intervene.in_force(taken, now_s)
        self.event(
            "onshore",
            f"took onboard's intervention on {t.intervention_target} ({t.intervention_id}) as the "
            f"mission's: its own ({current.command_id}) was refused ({answer.reason})",
        )

    def _next_intervention(self, t: Telemetry) -> None:
        """The mission's next intervention once onboard has done the one in hand."""
        current = self.intervene.message
        done = (
            current is not None and t.intervention_id == current.command_id and t.intervention_phase == "done"
        )
        if done and self.intervention_index + 1 < len(self.mission.interventions):
            self.intervention_index += 1
            self.intervene.replace(mission_intervention(self.mission, self.intervention_index))

    def step(self, inputs: OperatorInputs, now_s: float) -> OperatorOutputs:
        out = OperatorOutputs()
        if self.first_step_s is None:
            self.first_step_s = now_s
        for topic, message in inputs.tool_commands:
            self.commands[topic].replace(message)
        for ack in inputs.acks:
            out.answers.append(ack)  # the tools pick their own out
            self._answered(ack)
        for t in inputs.telemetry:
            self._telemetry(t, now_s)
        if not self.joined and now_s - self.first_step_s >= JOIN_WAIT_S:
            self.joined = True  # no telemetry: send the mission anyway, resent until answered
        if self.joined:
            self._resend(out, now_s)
        if now_s - self.last_beat_s >= HEARTBEAT_PERIOD_S:
            out.messages.append(("heartbeat", Heartbeat(0.0, True)))
            self.last_beat_s = now_s
        if now_s - self.last_status_s >= STATUS_PERIOD_S:
            out.status = self.status or self._idle_status()
            self.last_status_s = now_s
        return out

    def _answered(self, ack: CommandAck) -> None:
        """Onboard's answer to a command: into the history, and the command stops resending."""
        entry = self.history.get((f"op/{ack.command}", ack.command_id))
        if entry is not None:
            entry.update(answered=True, accepted=ack.accepted, reason=ack.reason)
        if self.commands[f"op/{ack.command}"].answered(ack):
            log.info(
                "%s command %d %s",
                ack.command,
                ack.command_id,
                "taken" if ack.accepted else f"refused: {ack.reason}",
            )

    def _resend(self, out: OperatorOutputs, now_s: float) -> None:
        """The satellite loses packets: each command is resent until onboard's answer comes back."""
        for command in self.commands.values():
            due = now_s - command.sent_s > self.mission.resend_period_s
            if command.message is None or command.answer is not None or not due or command.waiting():
                continue
            entry = self.history.setdefault(
                (command.topic, command.message.command_id),
                {
                    "command": command.topic.removeprefix("op/"),
                    "command_id": command.message.command_id,
                    "sends": 0,
                    "answered": False,
                    "accepted": False,
                    "reason": "",
                },
            )
            entry["sends"] = int(entry["sends"]) + 1  # type: ignore[call-overload]
            if command.sent_s == -float("inf"):
                out.first_sent.append(command.message)
            out.messages.append((command.topic, command.message))
            command.sent_s = now_s

    def _idle_status(self) -> MissionStatus:
        """What shore shows before onboard's first status."""
        return MissionStatus(
            mode="idle",
            waypoint_index=0,
            waypoints_total=0 if self.ground_station else len(self.mission.waypoints),
            position_error_m=0.0,
            heading_error_rad=0.0,
            arm_mode="idle",
            ee_position_error_m=0.0,
            ee_orientation_error_rad=0.0,
            failsafe="",
            failsafe_events=0,
            interventions_total=0 if self.ground_station else len(self.mission.interventions),
        )


def mission_intervention(mission: MissionConfig, index: int, command_id: int | None = None) -> Intervention:
    part, amount = mission.interventions[index]
    return Intervention(command_id if command_id is not None else new_id(), part, *intent_of(amount))


def mission_status(
    t: Telemetry,
    waypoints: Command[Waypoints],
    arm: Command[ArmGoal],
    offset: int = 0,
    intervene: Command[Intervention] | None = None,
    index: int = 0,
    total: int = 0,
    hold_m: float = math.inf,
) -> MissionStatus:
    """The mission as telemetry shows it; done once the vehicle holds its last waypoint (within
    `hold_m` of it), the end-effector its goal and onboard says the last intervention is done, all
    of the commands this station sent last. Waypoints count from the mission's first: `offset`
    were reached before the list in force began; interventions: `index` of `total` is in hand."""
    sent = waypoints.message
    flying = sent is not None and t.command_id == sent.command_id
    vehicle_done = flying and t.mode == "reached" and t.position_error_m <= hold_m
    arm_done = arm.message is None or (t.arm_command_id == arm.message.command_id and t.arm_mode == "reached")
    current = intervene.message if intervene is not None else None
    on_it = current is not None and t.intervention_id == current.command_id
    finished = 0
    if current is not None:  # the ones before the one in hand are done; it, once onboard says so
        finished = index + int(on_it and t.intervention_phase == "done")
    phase = t.intervention_phase if on_it else ""
    return MissionStatus(
        **_seen(t),
        waypoint_index=offset + t.waypoint_index if flying else offset,
        waypoints_total=offset + (len(sent.waypoints) if sent is not None else 0),
        done=vehicle_done and arm_done and finished >= total,
        interventions_done=finished,
        interventions_total=total,
        intervention_target=current.target if isinstance(current, Intervention) else "",
        intervention_phase=phase,
        intervention_reason=t.intervention_reason if on_it else "",
    )


def flown_status(t: Telemetry, hold_m: float) -> MissionStatus:
    """A ground station's mission as telemetry shows it: the waypoints onboard flies, done once the
    vehicle holds the last (within `hold_m` of it), unless they are a pilot's goal (`piloted`)."""
    mission = t.command_id >= 0 and not t.piloted and t.waypoints_total > 0
    done = (
        mission
        and t.mode == "reached"
        and t.waypoint_index >= t.waypoints_total
        and t.position_error_m <= hold_m
    )
    return MissionStatus(
        **_seen(t),
        waypoint_index=t.waypoint_index if mission else 0,
        waypoints_total=t.waypoints_total if mission else 0,
        done=done,
    )


def _seen(t: Telemetry) -> dict[str, Any]:
    """What a mission status shows of the telemetry as it is: the modes, the errors, the failsafe."""
    return {
        "mode": t.mode,
        "position_error_m": t.position_error_m,
        "heading_error_rad": abs(t.heading_error_rad),
        "arm_mode": t.arm_mode,
        "ee_position_error_m": float(np.linalg.norm(t.ee_position_error_m_world)),
        "ee_orientation_error_rad": t.ee_orientation_error_rad,
        "failsafe": t.failsafe,
        "failsafe_events": t.failsafe_events,
    }


class PerceptionSeen:
    """What shore was told of the vessel's perception over the run (PerceptionStatus), summed up
    for the summary: per source the points per second (mean, max and last report), how long
    each source fed the scene model [s, by the vessel's clock], the recognition's confidence."""

    def __init__(self) -> None:
        self.reports: list[tuple[float, PerceptionStatus]] = []  # (sender's stamp, status)

    def add(self, status: PerceptionStatus, stamp_s: float) -> None:
        self.reports.append((stamp_s, status))

    def summary(self) -> dict[str, object]:
        if not self.reports:
            return {}
        statuses = [status for _, status in self.reports]
        rates: dict[str, list[float]] = {}
        for status in statuses:
            for source, rate in status.points_per_s.items():
                rates.setdefault(source, []).append(rate)
        mapped_s: dict[str, float] = {}
        for (t0, status), (t1, _) in zip(self.reports, self.reports[1:], strict=False):
            if status.scene_source:
                mapped_s[status.scene_source] = mapped_s.get(status.scene_source, 0.0) + max(0.0, t1 - t0)
        confidence = [status.recognition_confidence for status in statuses]
        return {
            "reports": len(statuses),
            "points_per_s": {
                source: {"mean": float(np.mean(r)), "max": max(r), "last": r[-1]}
                for source, r in rates.items()
            },
            "scene_source_s": mapped_s,
            "scene_source": statuses[-1].scene_source,
            "recognition_confidence": {"last": confidence[-1], "max": max(confidence)},
            "recognition_method": statuses[-1].recognition_method,
        }
