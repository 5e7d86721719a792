"""The onshore station: the operator. Sends the mission (auto mode, waypoints, then an
end-effector goal) and whatever operator tools hand it (`abyss teleop`, `abyss op`), resends
each command over the lossy satellite link until onboard's answer comes back, hands that answer
to the tools, beats a heartbeat to the vessel, and publishes
the mission status as the operator sees it. It keeps its copy of the scene from the vessel's
octree stream (asking for a snapshot when it has none or missed an update) and the recognised
objects, and what the vessel says its perception works with; with `onshore.record_dir` it
leaves them there when it stops. Everything it receives,
and every hop's link statistics, goes to the rerun viewer (`viewer.py`) at its sender's stamp."""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path
from typing import TYPE_CHECKING

from abyss.bus.session import Bus, Inbox
from abyss.common.runfiles import CARRIED_OVER, read_json_list, write_whole
from abyss.common.workers import Workers
from abyss.config import Config, robot_of
from abyss.interface import keys
from abyss.interface.messages import (
    TOOL_COMMANDS,
    ArmGoal,
    CommandAck,
    Image,
    LinkStats,
    Message,
    PerceptionStatus,
    Received,
    RecognisedObjects,
    SceneUpdate,
    ShoreEvent,
    SonarImage,
    Telemetry,
    Waypoints,
)
from abyss.scene.export import save_snapshot
from abyss.scene.receiver import ShoreScene
from abyss.stations.onshore.core import Operator, OperatorInputs, PerceptionSeen
from abyss.stations.onshore.viewer import Sinks, Viewer

if TYPE_CHECKING:
    from abyss.mavlink.endpoint import Endpoint

PERIOD_S = 0.1
SAVE_PERIOD_S = 1.0  # both files are rewritten this often when they changed: a killed shore keeps them
log = logging.getLogger(__name__)


def loops(config: Config) -> tuple[str, ...]:
    """The station's named loops (lockstep runs no period before they are all there)."""
    return ("display",)


def run(config: Config, bus: Bus) -> None:
    """The I/O shell of `core.Operator`, the scene (`Scene`) and the viewer; with a ground station's
    endpoint (mavlink.enabled) in a thread of its own."""
    endpoint = _endpoint(config) if config.mavlink.enabled else None  # its port taken at start
    with Workers(bus.stop) as workers:
        if endpoint is not None:
            workers.start("mavlink", _serve, config, bus, endpoint)
        _display(config, bus)


def _display(config: Config, bus: Bus) -> None:
    record_dir = Path(config.onshore.record_dir) if config.onshore.record_dir else None
    history, events = (read_json_list(record_dir / name) if record_dir else [] for name in CARRIED_OVER)
    # a restarted shore goes on with what it had; with a ground station flying abyss's own vehicle,
    # the station's mission is the one judged
    ground_station = config.mavlink.enabled and not config.mavlink.autopilot  # with ArduSub: shore's mission
    operator = Operator(config.mission, history, events, ground_station=ground_station)
    sinks = Sinks(config.onshore, bus.system)
    viewer = Viewer(sinks.recording, robot_of(config)) if sinks.recording is not None else None
    scene = Scene(bus, config.onshore.scene_request_period_s, viewer, config.onshore.viewer_scene_period_s)
    inboxes = _Inboxes(bus)
    rate = bus.loop("display", PERIOD_S)
    saved: tuple[str, str] = ("", "")
    saved_s = -float("inf")
    told = len(operator.events)  # what an earlier life of this station saw was told then
    while rate.sleep():
        now_s = bus.clock.now_s()
        if scene.step(now_s):
            operator.event("vessel", "restarted: a new scene stream, kept on the map shore holds")
        _operate(bus, operator, inboxes, viewer, now_s)
        for event in operator.events[told:]:  # to the operator's tools, as it happens
            bus.observe(keys.shore_event_key(bus.system), ShoreEvent(**event))  # type: ignore[arg-type]
        told = len(operator.events)
        if record_dir and now_s - saved_s >= SAVE_PERIOD_S:
            saved, saved_s = _save(record_dir, operator, saved), now_s
    if record_dir:
        scene.save(record_dir)
        _save(record_dir, operator, saved)
    scene.show(bus.clock.now_s(), final=True)
    sinks.close()


class _Inboxes:
    """What the operator's loop reads: the vessel's telemetry, answers and frames, the links'
    statistics, and the operator tools' commands."""

    def __init__(self, bus: Bus) -> None:
        self.telemetry = bus.subscribe("vessel", "telemetry", Telemetry, maxlen=8)
        self.acks = bus.subscribe("vessel", "ack", CommandAck)
        self.images = bus.subscribe("vessel", "image", Image, maxlen=2)
        self.sonar = bus.subscribe("vessel", "sonar", SonarImage, maxlen=2)
        self.link_stats = bus.subscribe_key(keys.linkstats_key(bus.system, "*", "*"), LinkStats)
        self.tools: dict[str, Inbox[Message]] = {  # op/<topic> <- operator/<topic>, taken by query
            f"op/{topic}": bus.take_key(keys.operator_key(bus.system, topic), message)
            for topic, message in TOOL_COMMANDS
        }


def _operate(bus: Bus, operator: Operator, inboxes: _Inboxes, viewer: Viewer | None, now_s: float) -> None:
    """One step of the operator: what came in to the core, what it returns out, and to the viewer."""
    received = inboxes.telemetry.drain()
    out = operator.step(
        OperatorInputs(
            tool_commands=[
                (topic, r.message) for topic, inbox in inboxes.tools.items() for r in inbox.drain()
            ],
            acks=[r.message for r in inboxes.acks.drain()],
            telemetry=[r.message for r in received],
        ),
        now_s,
    )
    for ack in out.answers:
        bus.observe(keys.operator_key(bus.system, "ack"), ack)
    for topic, message in out.messages:
        bus.publish(topic, message)
    if out.status is not None:
        bus.observe(keys.mission_key(bus.system), out.status)
    if viewer:
        _show(viewer, bus.clock.stamp_s(), out.first_sent, received)
        for image in inboxes.images.drain():
            viewer.image(image.message, image.stamp_s)
        for ping in inboxes.sonar.drain():
            viewer.sonar(ping.message, ping.stamp_s)
        for stats in inboxes.link_stats.drain():
            viewer.link_stats(stats.message, stats.stamp_s)


def _save(record_dir: Path, operator: Operator, saved: tuple[str, str]) -> tuple[str, str]:
    """The command history and the events, each written (whole, then renamed) if it changed."""
    texts = (json.dumps(list(operator.history.values()), indent=2), json.dumps(operator.events, indent=2))
    for name, text, before in zip(CARRIED_OVER, texts, saved, strict=True):
        if text != before:
            write_whole(record_dir / name, text)
    return texts


def _show(
    viewer: Viewer,
    stamp_s: float,
    first_sent: list[Message],
    telemetry: list[Received[Telemetry]],
) -> None:
    """The telemetry, at its sender's stamp, and each command when it is first sent (`stamp_s`)."""
    for command in first_sent:
        if isinstance(command, Waypoints):
            viewer.waypoints(command, stamp_s)
        elif isinstance(command, ArmGoal):
            viewer.arm_goal(command, stamp_s)
    for r in telemetry:
        t = r.message
        viewer.telemetry(t, r.stamp_s)
        if t.intervention_target:
            viewer.intervention(
                r.stamp_s,
                t.sim_time_s,
                t.intervention_target,
                t.intervention_phase,
                t.intervention_reason,
                math.degrees(t.turned_rad),
                math.degrees(t.turn_goal_rad),
                t.gripper_opening_m * 1e3,
                t.gripper_force_n,
            )


class Scene:
    """The I/O shell of shore's scene stream (`abyss.scene.receiver.ShoreScene`), and the
    recognised objects and perception's status as the vessel tells them."""

    def __init__(
        self, bus: Bus, request_period_s: float, viewer: Viewer | None = None, viewer_period_s: float = 2.0
    ) -> None:
        self.bus = bus
        self.viewer = viewer
        self.viewer_period_s = viewer_period_s
        self._shown_s = -float("inf")  # when the whole scene last went to the viewer
        self._shown_applied = 0
        self.updates = bus.subscribe("vessel", "scene", SceneUpdate, maxlen=256)
        self.objects_inbox = bus.subscribe("vessel", "objects", RecognisedObjects, maxlen=4)
        self.perception_inbox = bus.subscribe("vessel", "perception", PerceptionStatus, maxlen=8)
        self.perception = PerceptionSeen()
        self.core = ShoreScene(request_period_s)
        self.receiver = self.core.receiver
        self.objects: RecognisedObjects | None = None

    def step(self, now_s: float) -> bool:
        """Whether a new scene stream went onto the map held (a restarted vessel)."""
        received = [(r, r.message) for r in self.updates.drain()]
        out = self.core.step([update for _, update in received], now_s)
        for ack in out.acks:
            self.bus.publish("scene_ack", ack)  # the vessel paces by these
        for index, reason in out.rejected:
            self.bus.reject(received[index][0].key, reason)
        for applied in out.applied:
            if self.viewer:
                stamp_s = received[applied.index][0].stamp_s
                self.viewer.scene_update(applied.centres_m_world, applied.colors, stamp_s, applied.sim_time_s)
        for r in self.objects_inbox.drain():
            self.objects = r.message
            if self.viewer:
                self.viewer.objects(r.message, r.stamp_s)
        for status in self.perception_inbox.drain():
            self.perception.add(status.message, status.stamp_s)
            if self.viewer:
                self.viewer.perception(status.message, status.stamp_s)
        self.show(now_s)
        if out.request is not None:
            self.bus.publish("scene_request", out.request)
        return out.new_stream

    def show(self, now_s: float, final: bool = False) -> None:
        """The whole scene to the viewer, when it changed, at most every `viewer_period_s`."""
        changed = self.receiver.applied != self._shown_applied
        if self.viewer and changed and (final or now_s - self._shown_s >= self.viewer_period_s):
            self.viewer.scene(
                *self.receiver.occupied_cells(),
                self.receiver.resolution_m,
                self.bus.clock.stamp_s(),
                self.core.sim_time_s,
            )
            self._shown_s, self._shown_applied = now_s, self.receiver.applied

    def save(self, directory: Path) -> None:
        """The final scene (a snapshot update) and what it took, in the run directory."""
        directory.mkdir(parents=True, exist_ok=True)
        save_snapshot(self.receiver, directory, self.core.sim_time_s, self.bus.clock.stamp_s())
        objects = self.objects
        stats = {
            "updates_applied": self.receiver.applied,
            "gaps": self.receiver.gaps,
            "snapshot_requests": self.core.requests,
            "update_bytes": self.core.update_bytes,
            "resolution_m": self.receiver.resolution_m,
            "occupied_cells": len(self.receiver.colors),
            "objects": {
                name: {"pose_world": pose.tolist(), "confidence": float(c)}
                for name, pose, c in zip(objects.names, objects.poses_world, objects.confidences, strict=True)
            }
            if objects
            else {},
            "recognition_method": objects.method if objects else "",
            "perception": self.perception.summary(),
        }
        (directory / "scene.json").write_text(json.dumps(stats, indent=2))


def _endpoint(config: Config) -> Endpoint:
    """The ground stations' endpoint (mavlink.enabled; pymavlink's, imported only then)."""
    from abyss.mavlink.endpoint import Endpoint

    return Endpoint(config, "onshore")


def _serve(config: Config, bus: Bus, endpoint: Endpoint) -> None:
    from abyss.mavlink.endpoint import serve

    serve(config, bus, endpoint)
