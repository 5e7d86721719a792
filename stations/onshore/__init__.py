"""The onshore station: the operator. Sends the mission (waypoints, then an end-effector goal)
and whatever operator tools hand it (`abyss teleop`), resends each command over the lossy
satellite link until telemetry shows it taken, beats a heartbeat to the vessel, and publishes
the mission status as the operator sees it."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from common import keys
from common.bus import Bus, Inbox
from common.config import Config
from common.messages import ArmGoal, Heartbeat, Message, MissionStatus, Telemetry, Waypoints
from common.rate import Rate

PERIOD_S = 0.1
STATUS_PERIOD_S = 0.25
HEARTBEAT_PERIOD_S = 1.0


@dataclass
class Command:
    """The latest command on one op key, resent until telemetry shows its id."""

    topic: str
    message: Waypoints | ArmGoal | None = None
    taken: bool = False
    sent_s: float = -float("inf")

    def replace(self, message: Message) -> None:
        assert isinstance(message, (Waypoints, ArmGoal))
        self.message, self.taken, self.sent_s = message, False, -float("inf")


def new_command_id() -> int:
    return int(time.time() * 1e3)


def run(config: Config, bus: Bus) -> None:
    mission = config.mission
    waypoints = Command("op/waypoints", Waypoints(new_command_id(), np.array(mission.waypoints)))
    arm = Command("op/arm")
    goal = mission.arm_goal()
    if goal is not None:
        arm.replace(ArmGoal(new_command_id() + 1, *goal))
    telemetry = bus.subscribe("vessel", "telemetry", maxlen=8)
    tools: dict[str, Inbox] = {
        "op/waypoints": bus.subscribe_key(keys.operator_key(bus.system, "waypoints"), "Waypoints"),
        "op/arm": bus.subscribe_key(keys.operator_key(bus.system, "arm"), "ArmGoal")}
    commands = {c.topic: c for c in (waypoints, arm)}
    rate = Rate(PERIOD_S, bus.stop)
    status: MissionStatus | None = None
    last_status_s = last_beat_s = -float("inf")
    while rate.sleep():
        now_s = time.monotonic()
        for topic, inbox in tools.items():
            for received in inbox.drain():
                commands[topic].replace(received.message)
        latest = telemetry.latest()
        if latest is not None:
            assert isinstance(latest.message, Telemetry)
            status = mission_status(latest.message, waypoints, arm)
        # the satellite loses packets: resend each command until telemetry shows it taken
        for command in commands.values():
            due = now_s - command.sent_s > mission.resend_period_s
            if command.message is not None and not command.taken and due:
                bus.publish(command.topic, command.message)
                command.sent_s = now_s
        if now_s - last_beat_s >= HEARTBEAT_PERIOD_S:
            bus.publish("heartbeat", Heartbeat(0.0, True))
            last_beat_s = now_s
        if now_s - last_status_s >= STATUS_PERIOD_S:
            bus.observe(keys.mission_key(bus.system), status or MissionStatus(
                mode="idle", waypoint_index=0, waypoints_total=len(mission.waypoints), position_error_m=0.0,
                heading_error_rad=0.0, arm_mode="idle", ee_position_error_m=0.0, ee_orientation_error_rad=0.0,
                failsafe="", failsafe_events=0))
            last_status_s = now_s


def mission_status(t: Telemetry, waypoints: Command, arm: Command) -> MissionStatus:
    """The mission as telemetry shows it; done once the vehicle holds its last waypoint and
    the end-effector its goal, both of the commands this station sent last."""
    assert isinstance(waypoints.message, Waypoints)
    waypoints.taken = waypoints.taken or t.command_id == waypoints.message.command_id
    if arm.message is not None:
        arm.taken = arm.taken or t.arm_command_id == arm.message.command_id
    arm_done = arm.message is None or (arm.taken and t.arm_mode == "reached")
    return MissionStatus(
        mode=t.mode, waypoint_index=t.waypoint_index, waypoints_total=len(waypoints.message.waypoints),
        position_error_m=t.position_error_m, heading_error_rad=abs(t.heading_error_rad), arm_mode=t.arm_mode,
        ee_position_error_m=float(np.linalg.norm(t.ee_position_error_m_world)),
        ee_orientation_error_rad=t.ee_orientation_error_rad, failsafe=t.failsafe,
        failsafe_events=t.failsafe_events, done=waypoints.taken and t.mode == "reached" and arm_done)
