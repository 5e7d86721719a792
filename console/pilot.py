"""`abyss console`: the pilot's console, one web page on this machine to fly the mission from. It
joins the system on shore's own network as an operator's tool (as `abyss op` does) and shows only
what reached shore across the satellite: the vessel's relay of onboard's telemetry, its relayed
camera frame and the parts it recognised, and shore's own mission status, each with its age.
Its commands take `abyss op`'s path (handed to the onshore station on the operator keys, which
takes them and resends them down the satellite until onboard's answer comes back: the tools
never resend), and each shows that answer. It
keeps a list of alerts: the failsafe entered and left, a command refused, an intervention failed,
the arm blocked, a waypoint missed, a station lost or restarted, the vessel's telemetry gone
silent. Every command any operator's tool hands shore shows here with who sent it, so a second
console sees the first one's. The page (`console/web/`) polls `/state` twice a second.
`console.server` serves it."""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
import zenoh

from abyss.bus.session import message_of
from abyss.common.errors import BadInput, BusError
from abyss.common.geometry import roll_pitch_of
from abyss.console.access import operator_name
from abyss.console.op import INTENTS, Command, command_of, hand_command, sender_of, text_of
from abyss.console.teleop import Goals, Target
from abyss.description.models.panel import Panel
from abyss.interface import keys
from abyss.interface.messages import (
    TOOL_COMMANDS,
    CommandAck,
    Image,
    LinkStats,
    MissionStatus,
    PerceptionStatus,
    RecognisedObjects,
    ShoreEvent,
    SonarImage,
    Telemetry,
    new_id,
)
from abyss.interface.sonar_frames import decode_polar, fan

# what the page shows of each hop's statistics (linkemu's keys): delays [ms], the queue, losses
LINK_FIELDS = ("delay_p50_ms", "delay_p99_ms", "in_flight", "messages_lost", "losses", "queue_drops")
SILENT_S = 3.0  # the vessel's telemetry older than this: an alert (the satellite or the vessel lost)
KEPT_ALERTS = 50
MAX_STEP = 1.0  # a teleop step's largest [m or rad]: the page sends a few centimetres at a time
log = logging.getLogger(__name__)


@dataclass
class Sent:
    """A command the console sent, and onboard's answer once it came."""

    command: Command
    kind: str
    text: str
    topic: str
    sent_s: float  # wall [s], when shore took it (another tool's: when this console saw it)
    by: str = ""  # who sent it: "" this console, else the tool's signature (op.hand_command)
    answer: CommandAck | None = None
    answered_s: float = 0.0  # wall [s], when onboard's answer reached this console

    def view(self) -> dict[str, Any]:
        state = "sent" if self.answer is None else ("taken" if self.answer.accepted else "refused")
        return {
            "id": self.command.command_id,
            "kind": self.kind,
            "text": self.text,
            "state": state,
            "reason": self.answer.reason if self.answer is not None else "",
            "by": self.by,
            "sent_s": self.sent_s,
            "answered_s": self.answered_s,
        }


@dataclass
class Pilot:
    """What the page shows and what it sent: updated by Zenoh's callbacks, read by the server's
    threads, under one lock."""

    session: zenoh.Session
    system: str
    panel: Panel  # the running site's, that commands are checked against (its description)
    by: str = field(default_factory=lambda: operator_name("console"))  # this console, to the others
    lock: threading.Lock = field(default_factory=threading.Lock)
    latest: dict[str, tuple[float, Any]] = field(default_factory=dict)  # what -> (arrival [s, wall], message)
    images: dict[str, tuple[float, int, bytes]] = field(default_factory=dict)  # path -> arrival, count, bytes
    links: dict[tuple[str, str], tuple[float, LinkStats]] = field(default_factory=dict)  # (hop, direction)
    sent: dict[int, Sent] = field(default_factory=dict)
    alerts: list[dict[str, Any]] = field(default_factory=list)
    goals: Goals = field(default_factory=Goals)  # teleop's, started from the telemetry as abyss teleop's
    teleop_sent: int = 0
    others_teleop: dict[str, int] = field(default_factory=dict)  # teleop goals other tools sent, by sender
    stations: dict[str, bool] = field(default_factory=dict)  # station -> its liveliness token held
    _before: Telemetry | None = None  # the telemetry before the latest, for what changed
    _silent: bool = False

    def start(self) -> list[Any]:
        """Subscribe to what reached shore, the commands of every operator's tool, and the
        stations' liveliness; the subscribers (keep them)."""
        take = {
            keys.spec("vessel", "telemetry").key(self.system): (Telemetry, self._telemetry),
            keys.mission_key(self.system): (MissionStatus, lambda m: self._keep("mission", m)),
            keys.spec("vessel", "objects").key(self.system): (
                RecognisedObjects,
                lambda m: self._keep("objects", m),
            ),
            keys.spec("vessel", "perception").key(self.system): (
                PerceptionStatus,
                lambda m: self._keep("perception", m),
            ),
            keys.spec("vessel", "image").key(self.system): (Image, self._image),
            keys.spec("vessel", "sonar").key(self.system): (SonarImage, self._sonar),
            keys.linkstats_key(self.system, "*", "*"): (LinkStats, self._link),
            keys.operator_key(self.system, "ack"): (CommandAck, self._answer),
            keys.shore_event_key(self.system): (ShoreEvent, lambda e: self._alert(f"{e.station} {e.event}")),
        }

        def on(cls: Any, handler: Any) -> Any:
            def callback(sample: zenoh.Sample) -> None:
                message = message_of(sample, cls)
                if message is not None:
                    handler(message)

            return callback

        def on_command(topic: str, cls: type) -> Any:
            def callback(sample: zenoh.Sample) -> None:
                command = message_of(sample, cls)
                if command is not None:
                    self._seen(topic, command, *sender_of(sample))

            return callback

        return [
            *(self.session.declare_subscriber(k, on(cls, handler)) for k, (cls, handler) in take.items()),
            *(
                self.session.declare_subscriber(keys.operator_key(self.system, topic), on_command(topic, cls))
                for topic, cls in TOOL_COMMANDS
            ),
            self.session.liveliness().declare_subscriber(
                keys.alive_key(self.system, "*"), self._alive, history=True
            ),
        ]

    def _keep(self, what: str, message: Any) -> None:
        with self.lock:
            self.latest[what] = (time.time(), message)

    def _telemetry(self, telemetry: Telemetry) -> None:
        with self.lock:
            self.latest["telemetry"] = (time.time(), telemetry)
            self.goals.start_from(telemetry)
            for alert in alerts_of(self._before, telemetry):
                self._alert(alert)
            self._before = telemetry
            if self._silent:
                self._alert("the vessel's telemetry reaches shore again")
                self._silent = False

    def _image(self, image: Image) -> None:
        if image.encoding == "jpeg":
            self._keep_image("/frame.jpg", image.data)

    def _sonar(self, sonar: SonarImage) -> None:
        """The sonar's fan seen from above, drawn here once (0.2 Hz) in a sonar display's colours
        (black at the noise floor, through red to yellow at the strongest echo), served as a PNG."""
        try:
            drawn, png = cv2.imencode(
                ".png", cv2.applyColorMap(fan(sonar, decode_polar(sonar)), cv2.COLORMAP_INFERNO)
            )
        except BadInput as exc:
            log.warning("a sonar frame that does not decode, not shown: %s", exc)
            return
        if drawn:
            self._keep_image("/sonar.png", png.tobytes())
            self._keep("sonar", sonar)

    def _keep_image(self, path: str, data: bytes) -> None:
        with self.lock:
            count = self.images[path][1] + 1 if path in self.images else 1
            self.images[path] = (time.time(), count, data)

    def _link(self, stats: LinkStats) -> None:
        with self.lock:
            self.links[stats.hop, stats.direction] = (time.time(), stats)

    def _alive(self, sample: zenoh.Sample) -> None:
        """A station's liveliness token came or went: a station lost, or back (restarted)."""
        station = str(sample.key_expr).split("/")[2]
        up = sample.kind == zenoh.SampleKind.PUT
        with self.lock:
            if station in self.stations and self.stations[station] != up:
                self._alert(f"station {station} back (restarted)" if up else f"station {station} lost")
            self.stations[station] = up

    def _seen(self, topic: str, command: Command, by: str, teleop: bool) -> None:
        """A command some operator's tool handed shore: another's is listed with its sender (a
        teleop goal only counted: they come twice a second)."""
        with self.lock:
            if command.command_id in self.sent or by == self.by:
                return
            if teleop:
                self.others_teleop[by] = self.others_teleop.get(by, 0) + 1
                return
            now = time.time()
            self.sent[command.command_id] = Sent(command, topic, text_of(command), topic, now, by)

    def _answer(self, ack: CommandAck) -> None:
        with self.lock:
            sent = self.sent.get(ack.command_id)
            if sent is None or sent.topic != ack.command or sent.answer is not None:
                return
            sent.answer, sent.answered_s = ack, time.time()
            if not ack.accepted:
                by = f" (sent by {sent.by})" if sent.by else ""
                self._alert(f"{sent.kind} {sent.text} refused{by}: {ack.reason}")

    def _alert(self, text: str) -> None:
        """An alert (the caller holds the lock)."""
        self.alerts.append({"wall_s": time.time(), "text": text})
        del self.alerts[:-KEPT_ALERTS]

    def send(self, kind: str, text: str, amount: str = "") -> int:
        """A command as `abyss op KIND TEXT` makes it (ConfigError/BadInput: refused here, sent
        nowhere); its id."""
        command = command_of(kind, text, new_id(), amount, self.panel)
        topic = "intervene" if kind in INTENTS else kind
        now = time.time()
        with self.lock:
            self.sent[command.command_id] = Sent(command, kind, f"{text} {amount}".strip(), topic, now)
        try:  # shore takes it, and resends it until onboard answers
            hand_command(self.session, self.system, topic, command, self.by)
        except (BusError, BadInput):
            with self.lock:
                del self.sent[command.command_id]
            raise
        return command.command_id

    def nudge(self, target: Target, translation_m: list[float], rotation_rad: list[float]) -> None:
        """Teleop: move the vehicle's or the end-effector's goal by a step in the vehicle's heading
        frame (forward, left, up [m]; roll, pitch, yaw [rad]) and send it, as `abyss teleop` does."""
        step = [float(v) for v in (*translation_m, *rotation_rad)]
        if target not in ("vehicle", "arm") or len(step) != 6 or not all(abs(v) <= MAX_STEP for v in step):
            raise BadInput(f"a teleop step is a target (vehicle, arm) and 6 values each within {MAX_STEP}")
        with self.lock:
            if self.goals.vehicle is None:
                raise BadInput("no telemetry from the vessel yet: nothing to start the goal from")
            command = self.goals.move(target, np.array(step[:3]), np.array(step[3:]))
            self.teleop_sent += 1
        topic = "waypoints" if target == "vehicle" else "arm"
        hand_command(self.session, self.system, topic, command, self.by, teleop=True)

    def watch(self) -> None:
        """The vessel's silence noticed (the server calls it twice a second)."""
        now = time.time()
        with self.lock:
            telemetry = self.latest.get("telemetry")
            if telemetry is not None and now - telemetry[0] > SILENT_S and not self._silent:
                self._silent = True
                self._alert(
                    f"no telemetry from the vessel for {now - telemetry[0]:.0f} s (satellite or vessel lost)"
                )

    def state(self) -> dict[str, Any]:
        """What the page shows, each with its age [s]."""
        now = time.time()
        with self.lock:
            shown: dict[str, Any] = {"wall_s": now, "system": self.system}
            for what, (arrived, message) in self.latest.items():
                shown[what] = {"age_s": now - arrived, **_fields(message)}
            for path, (arrived, count, _) in self.images.items():
                name = path.strip("/").split(".")[0]  # frame, sonar: beside the sonar's fields
                shown[name] = shown.get(name, {}) | {"age_s": now - arrived, "count": count}
            shown["links"] = [
                {"hop": hop, "direction": direction, "age_s": now - arrived, "profile": stats.profile}
                | {k: stats.stats[k] for k in LINK_FIELDS if k in stats.stats}
                for (hop, direction), (arrived, stats) in sorted(self.links.items())
            ]
            shown["commands"] = [s.view() for s in sorted(self.sent.values(), key=lambda s: -s.sent_s)][:20]
            shown["alerts"] = list(reversed(self.alerts))
            shown["teleop_sent"] = self.teleop_sent
            shown["others_teleop"] = dict(self.others_teleop)
            shown["stations"] = dict(self.stations)
            shown["by"] = self.by
        return shown

    def image(self, path: str) -> bytes | None:
        """The latest relayed frame (/frame.jpg) or sonar fan (/sonar.png), if one came."""
        with self.lock:
            return self.images[path][2] if path in self.images else None


def alerts_of(before: Telemetry | None, now: Telemetry) -> list[str]:
    """What the telemetry says changed that the pilot must be told: the failsafe entered or
    left, the arm blocked, a waypoint missed, an intervention failed. A station's restart is shore's
    to tell (ShoreEvent: shore alone tells one from the telemetry, and says what it did)."""
    failsafe, arm_mode, mode, intervention = ("", "", "", (-1, ""))
    if before is not None:
        failsafe, arm_mode, mode = before.failsafe, before.arm_mode, before.mode
        intervention = (before.intervention_id, before.intervention_phase)
    said = []
    if now.failsafe != failsafe:
        said.append(f"failsafe: {now.failsafe}" if now.failsafe else "failsafe left")
    if now.arm_mode == "blocked" != arm_mode:
        said.append(f"the arm blocked (intervention: {now.intervention_target or 'none'})")
    if now.mode == "missed" != mode:
        said.append(f"waypoint {now.waypoint_index + 1} of {now.waypoints_total} missed: its time ran out")
    if now.intervention_phase == "failed" and (now.intervention_id, "failed") != intervention:
        said.append(f"the intervention on {now.intervention_target} failed: {now.intervention_reason}")
    return said


def _fields(message: Any) -> dict[str, Any]:
    """A message's fields the page reads, as JSON values."""
    if isinstance(message, Telemetry):
        x, y, z = (float(v) for v in message.position_m_world)
        roll_rad, pitch_rad = roll_pitch_of(message.orientation_wxyz_world)
        return {
            "position_m_world": [x, y, z],
            "depth_m": -z,
            "heading_rad": message.yaw_rad,
            "roll_rad": roll_rad,
            "pitch_rad": pitch_rad,
            "speed_mps": float(np.linalg.norm(message.velocity_mps_body)),
            "effort": [float(v) for v in message.effort_body],
            "mode": message.mode,
            "arm_mode": message.arm_mode,
            "operator_mode": message.operator_mode,
            "failsafe": message.failsafe,
            "waypoint_index": message.waypoint_index,
            "waypoints_total": message.waypoints_total,
            "intervention_target": message.intervention_target,
            "intervention_phase": message.intervention_phase,
            "intervention_reason": message.intervention_reason,
            "gripper_opening_m": message.gripper_opening_m,
            "arm_positions_rad": [float(v) for v in message.arm_positions_rad],
            "sim_time_s": message.sim_time_s,
        }
    if isinstance(message, MissionStatus):
        return {
            "mode": message.mode,
            "waypoint_index": message.waypoint_index,
            "waypoints_total": message.waypoints_total,
            "position_error_m": message.position_error_m,
            "done": message.done,
            "interventions_done": message.interventions_done,
            "interventions_total": message.interventions_total,
            "intervention_phase": message.intervention_phase,
        }
    if isinstance(message, PerceptionStatus):
        return {
            "scene_source": message.scene_source,
            "recognition_confidence": message.recognition_confidence,
            "points_per_s": dict(message.points_per_s),
            "scene_backlog_cells": message.scene_backlog_cells,
        }
    if isinstance(message, SonarImage):
        return {"range_max_m": message.range_max_m, "horizontal_fov_rad": message.horizontal_fov_rad}
    assert isinstance(message, RecognisedObjects)
    return {
        "names": list(message.names),
        "positions_m_world": message.poses_world[:, :3].round(3).tolist(),
        "half_sizes_m": message.half_sizes_m.round(3).tolist(),
        "method": message.method,
    }
