"""The onshore station: the operator. Sends the mission (auto mode, waypoints, then an
end-effector goal) and whatever operator tools hand it (`abyss teleop`, `abyss op`), resends
each command over the lossy satellite link until onboard's answer comes back, hands that answer
to the tools, beats a heartbeat to the vessel, and publishes
the mission status as the operator sees it. It keeps its copy of the scene from the vessel's
octree stream (asking for a snapshot when it has none or missed an update) and the recognised
objects; with `onshore.record_dir` it leaves them there when it stops. Everything it receives,
and every hop's link statistics, goes to the rerun viewer (`viewer.py`) at its sender's stamp."""

from __future__ import annotations

import json
import logging
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from abyss.common import keys
from abyss.common.bus import Bus, Inbox
from abyss.common.config import Config
from abyss.common.messages import (
    ArmGoal,
    CommandAck,
    Heartbeat,
    Image,
    LinkStats,
    Message,
    MissionStatus,
    OperatorMode,
    RecognisedObjects,
    SceneRequest,
    SceneUpdate,
    Telemetry,
    Waypoints,
    encode,
)
from abyss.common.rate import Rate
from abyss.common.scene import SceneReceiver
from abyss.stations.onshore.viewer import Sinks, Viewer

PERIOD_S = 0.1
STATUS_PERIOD_S = 0.25
HEARTBEAT_PERIOD_S = 1.0
COMMANDS_FILE = "commands.json"  # every command shore sent, how often, and onboard's answer
SCENE_FILE = "scene.msgpack"  # the final scene, a snapshot SceneUpdate; `abyss scene export` reads it
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


def run(config: Config, bus: Bus) -> None:
    mission = config.mission
    first_id = new_command_id()
    mode = Command("op/mode", OperatorMode(first_id, "auto"))
    waypoints = Command("op/waypoints", Waypoints(first_id + 1, np.array(mission.waypoints)))
    arm = Command("op/arm")
    goal = mission.arm_goal()
    if goal is not None:
        arm.replace(ArmGoal(first_id + 2, *goal))
    telemetry = bus.subscribe("vessel", "telemetry", maxlen=8)
    acks = bus.subscribe("vessel", "ack")
    images = bus.subscribe("vessel", "image", maxlen=2)
    link_stats = bus.subscribe_key(keys.linkstats_key(bus.system, "*", "*"), "LinkStats")
    sinks = Sinks(config.onshore, bus.system)
    viewer = Viewer(sinks.recording) if sinks.recording is not None else None
    commands = {c.topic: c for c in (mode, waypoints, arm)}
    history: dict[tuple[str, int], dict[str, object]] = {}  # every command sent, and its fate
    tools: dict[str, Inbox] = {  # op/<topic> <- operator/<topic>
        c.topic: bus.subscribe_key(keys.operator_key(bus.system, c.topic.removeprefix("op/")), message)
        for c, message in ((mode, "OperatorMode"), (waypoints, "Waypoints"), (arm, "ArmGoal"))}
    scene = Scene(bus, config.onshore.scene_request_period_s, viewer, config.onshore.viewer_scene_period_s)
    rate = Rate(PERIOD_S, bus.stop)
    status: MissionStatus | None = None
    last_status_s = last_beat_s = -float("inf")
    while rate.sleep():
        now_s = time.monotonic()
        scene.step(now_s)
        for topic, inbox in tools.items():
            for received in inbox.drain():
                commands[topic].replace(received.message)
        for received in acks.drain():
            ack = received.message
            assert isinstance(ack, CommandAck)
            bus.observe(keys.operator_key(bus.system, "ack"), ack)  # the tools pick their own out
            entry = history.get((f"op/{ack.command}", ack.command_id))
            if entry is not None:
                entry.update(answered=True, accepted=ack.accepted, reason=ack.reason)
            if commands[f"op/{ack.command}"].answered(ack):
                log.info("%s command %d %s", ack.command, ack.command_id,
                         "taken" if ack.accepted else f"refused: {ack.reason}")
        for received in telemetry.drain():
            assert isinstance(received.message, Telemetry)
            status = mission_status(received.message, waypoints, arm)
            if viewer:
                viewer.telemetry(received.message, received.stamp_s)
        for received in (*images.drain(), *link_stats.drain()) if viewer else ():
            if isinstance(received.message, Image):
                viewer.image(received.message, received.stamp_s)
            elif isinstance(received.message, LinkStats):
                viewer.link_stats(received.message, received.stamp_s)
        # the satellite loses packets: resend each command until onboard's answer comes back
        for command in commands.values():
            due = now_s - command.sent_s > mission.resend_period_s
            if command.message is not None and command.answer is None and due:
                entry = history.setdefault((command.topic, command.message.command_id), {
                    "command": command.topic.removeprefix("op/"), "command_id": command.message.command_id,
                    "sends": 0, "answered": False, "accepted": False, "reason": ""})
                entry["sends"] = int(entry["sends"]) + 1  # type: ignore[call-overload]
                if viewer and command.sent_s == -float("inf"):  # sent for the first time
                    if isinstance(command.message, Waypoints):
                        viewer.waypoints(command.message, time.time())
                    elif isinstance(command.message, ArmGoal):
                        viewer.arm_goal(command.message, time.time())
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
    if config.onshore.record_dir:
        record_dir = Path(config.onshore.record_dir)
        scene.save(record_dir)
        (record_dir / COMMANDS_FILE).write_text(json.dumps(list(history.values()), indent=2))
    scene.show(time.monotonic(), final=True)
    sinks.close()


class Scene:
    """Shore's copy of the scene and the recognised objects."""

    def __init__(self, bus: Bus, request_period_s: float, viewer: Viewer | None = None,
                 viewer_period_s: float = 2.0) -> None:
        self.bus = bus
        self.request_period_s = request_period_s
        self.viewer = viewer
        self.viewer_period_s = viewer_period_s
        self._shown_s = -float("inf")  # when the whole scene last went to the viewer
        self._shown_applied = 0
        self.updates = bus.subscribe("vessel", "scene", maxlen=256)
        self.objects_inbox = bus.subscribe("vessel", "objects", maxlen=4)
        self.receiver = SceneReceiver()
        self.objects: RecognisedObjects | None = None
        self.requests = 0
        self.update_bytes = 0
        self.sim_time_s = 0.0
        self._last_request_s = -float("inf")

    def step(self, now_s: float) -> None:
        for received in self.updates.drain():
            assert isinstance(received.message, SceneUpdate)
            try:
                outcome = self.receiver.apply(received.message)
            except ValueError as exc:  # octree bytes that do not decode
                self.bus.reject(received.key, str(exc))
                outcome = "gap"
            if outcome == "applied":
                self.update_bytes += len(received.message.octree) + received.message.colors.nbytes
                self.sim_time_s = received.message.sim_time_s
                if self.viewer:
                    self.viewer.scene_update(self.receiver.latest_centres_m, self.receiver.latest_colors,
                                             received.stamp_s, self.sim_time_s)
            elif outcome == "gap":
                log.info("scene update %d does not follow %d: asking for a snapshot",
                         received.message.scene_seq, self.receiver.last_seq)
                self._last_request_s = -float("inf")
        for received in self.objects_inbox.drain():
            assert isinstance(received.message, RecognisedObjects)
            self.objects = received.message
            if self.viewer:
                self.viewer.objects(received.message, received.stamp_s)
        self.show(now_s)
        if self.receiver.tree is None and now_s - self._last_request_s >= self.request_period_s:
            reason = "no map yet" if self.receiver.applied == 0 else "missed an update"
            self.bus.publish("scene_request", SceneRequest(self.receiver.last_seq, reason))
            self.requests += 1
            self._last_request_s = now_s

    def show(self, now_s: float, final: bool = False) -> None:
        """The whole scene to the viewer, when it changed, at most every `viewer_period_s`."""
        changed = self.receiver.applied != self._shown_applied
        if self.viewer and changed and (final or now_s - self._shown_s >= self.viewer_period_s):
            self.viewer.scene(*self.receiver.occupied_cells(), self.receiver.resolution_m, time.time(),
                              self.sim_time_s)
            self._shown_s, self._shown_applied = now_s, self.receiver.applied

    def save(self, directory: Path) -> None:
        """The final scene (a snapshot update) and what it took, in the run directory."""
        directory.mkdir(parents=True, exist_ok=True)
        snapshot = self.receiver.snapshot(self.sim_time_s)
        if snapshot is not None:
            (directory / SCENE_FILE).write_bytes(encode(snapshot, 0, time.time()))
        stats = {"updates_applied": self.receiver.applied, "gaps": self.receiver.gaps,
                 "snapshot_requests": self.requests, "update_bytes": self.update_bytes,
                 "resolution_m": self.receiver.resolution_m,
                 "occupied_cells": len(self.receiver.colors),
                 "objects": {name: {"pose_world": pose.tolist(), "confidence": float(c)}
                             for name, pose, c in zip(self.objects.names, self.objects.poses_world,
                                                      self.objects.confidences, strict=True)}
                 if self.objects else {},
                 "recognition_method": self.objects.method if self.objects else ""}
        (directory / "scene.json").write_text(json.dumps(stats, indent=2))


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
