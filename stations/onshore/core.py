"""The operator's core on shore, without Zenoh: the mission's commands (auto mode, waypoints,
then an end-effector goal) and whatever the operator's tools hand in, each resent over the
lossy satellite until onboard's answer comes back; every command's fate; a heartbeat to the
vessel; the mission status as the operator sees it. A restarted onshore station starts the
mission's commands anew; onboard answers a command it already took without taking it again."""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np

from abyss.common.config import MissionConfig
from abyss.common.messages import (
    ArmGoal,
    CommandAck,
    Heartbeat,
    Message,
    MissionStatus,
    OperatorMode,
    Telemetry,
    Waypoints,
)

HEARTBEAT_PERIOD_S = 1.0
STATUS_PERIOD_S = 0.25
log = logging.getLogger(__name__)


@dataclass
class Command:
    """The latest command on one op key, resent until onboard answers it."""

    topic: str
    message: Waypoints | ArmGoal | OperatorMode | None = None
    answer: CommandAck | None = None
    sent_s: float = -float("inf")

    def replace(self, message: Message) -> None:
        assert isinstance(message, (Waypoints, ArmGoal, OperatorMode))
        self.message, self.answer, self.sent_s = message, None, -float("inf")

    def answered(self, ack: CommandAck) -> bool:
        """Take onboard's answer if it is to this command."""
        if self.message is None or self.message.command_id != ack.command_id or self.answer is not None:
            return False
        self.answer = ack
        return True


def new_command_id() -> int:
    return int(time.time() * 1e3)


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
    def __init__(self, mission: MissionConfig) -> None:
        self.mission = mission
        first_id = new_command_id()
        self.mode = Command("op/mode", OperatorMode(first_id, "auto"))
        self.waypoints = Command("op/waypoints", Waypoints(first_id + 1, np.array(mission.waypoints)))
        self.arm = Command("op/arm")
        goal = mission.arm_goal()
        if goal is not None:
            self.arm.replace(ArmGoal(first_id + 2, *goal))
        self.commands = {c.topic: c for c in (self.mode, self.waypoints, self.arm)}
        self.history: dict[tuple[str, int], dict[str, object]] = {}  # every command sent, and its fate
        self.status: MissionStatus | None = None
        self.last_status_s = self.last_beat_s = -float("inf")

    def step(self, inputs: OperatorInputs, now_s: float) -> OperatorOutputs:
        out = OperatorOutputs()
        for topic, message in inputs.tool_commands:
            self.commands[topic].replace(message)
        for ack in inputs.acks:
            out.answers.append(ack)  # the tools pick their own out
            entry = self.history.get((f"op/{ack.command}", ack.command_id))
            if entry is not None:
                entry.update(answered=True, accepted=ack.accepted, reason=ack.reason)
            if self.commands[f"op/{ack.command}"].answered(ack):
                log.info("%s command %d %s", ack.command, ack.command_id,
                         "taken" if ack.accepted else f"refused: {ack.reason}")
        for t in inputs.telemetry:
            self.status = mission_status(t, self.waypoints, self.arm)
        # the satellite loses packets: resend each command until onboard's answer comes back
        for command in self.commands.values():
            due = now_s - command.sent_s > self.mission.resend_period_s
            if command.message is not None and command.answer is None and due:
                entry = self.history.setdefault((command.topic, command.message.command_id), {
                    "command": command.topic.removeprefix("op/"), "command_id": command.message.command_id,
                    "sends": 0, "answered": False, "accepted": False, "reason": ""})
                entry["sends"] = int(entry["sends"]) + 1  # type: ignore[call-overload]
                if command.sent_s == -float("inf"):
                    out.first_sent.append(command.message)
                out.messages.append((command.topic, command.message))
                command.sent_s = now_s
        if now_s - self.last_beat_s >= HEARTBEAT_PERIOD_S:
            out.messages.append(("heartbeat", Heartbeat(0.0, True)))
            self.last_beat_s = now_s
        if now_s - self.last_status_s >= STATUS_PERIOD_S:
            out.status = self.status or MissionStatus(
                mode="idle", waypoint_index=0, waypoints_total=len(self.mission.waypoints),
                position_error_m=0.0,
                heading_error_rad=0.0, arm_mode="idle", ee_position_error_m=0.0, ee_orientation_error_rad=0.0,
                failsafe="", failsafe_events=0)
            self.last_status_s = now_s
        return out


def mission_status(t: Telemetry, waypoints: Command, arm: Command) -> MissionStatus:
    """The mission as telemetry shows it; done once the vehicle holds its last waypoint and
    the end-effector its goal, both of the commands this station sent last."""
    assert isinstance(waypoints.message, Waypoints)
    vehicle_done = t.command_id == waypoints.message.command_id and t.mode == "reached"
    arm_done = arm.message is None or (t.arm_command_id == arm.message.command_id and t.arm_mode == "reached")
    return MissionStatus(
        mode=t.mode, waypoint_index=t.waypoint_index, waypoints_total=len(waypoints.message.waypoints),
        position_error_m=t.position_error_m, heading_error_rad=abs(t.heading_error_rad), arm_mode=t.arm_mode,
        ee_position_error_m=float(np.linalg.norm(t.ee_position_error_m_world)),
        ee_orientation_error_rad=t.ee_orientation_error_rad, failsafe=t.failsafe,
        failsafe_events=t.failsafe_events, done=vehicle_done and arm_done)
