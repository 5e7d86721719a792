"""`abyss console`: the pilot's console, one web page on this machine to fly the mission from. It
joins the system on shore's own network as an operator's tool (as `abyss op` does) and shows only
what reached shore across the satellite: the vessel's relay of onboard's telemetry, its relayed
camera frame and the parts it recognised, and shore's own mission status, each with its age.
Its commands take `abyss op`'s path (the operator keys to the onshore station, which sends them
down the satellite), resent until onboard's answer comes back, and each shows that answer. It
keeps a list of alerts: the failsafe entered and left, a command refused, an intervention failed,
the vessel's telemetry gone silent. The page (`console/web/`) polls `/state` twice a second.

The server binds to 127.0.0.1 alone: on a network, commands would need the operator's credential,
which this console does not ask for yet."""

from __future__ import annotations

import json
import logging
import threading
import time
from dataclasses import dataclass, field
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from abyss.common import keys
from abyss.common.bus import client_config, message_of, open_session
from abyss.common.errors import AbyssError, BadInput, ConfigError
from abyss.common.messages import (
    CommandAck,
    Image,
    MissionStatus,
    RecognisedObjects,
    Telemetry,
    encode,
    new_id,
)
from abyss.common.site import site_at
from abyss.console.op import INTENTS, Command, command_of
from abyss.console.teleop import Goals, Target

WEB = Path(__file__).parent / "web"
FILES = {"/": ("index.html", "text/html"), "/console.js": ("console.js", "text/javascript")}
RESEND_PERIOD_S = 2.0  # a command not answered yet is sent again, as `abyss op` does
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
    sent_s: float  # wall [s], the first send
    last_sent_s: float
    answer: CommandAck | None = None

    def view(self) -> dict[str, Any]:
        state = "sent" if self.answer is None else ("taken" if self.answer.accepted else "refused")
        return {
            "id": self.command.command_id,
            "kind": self.kind,
            "text": self.text,
            "state": state,
            "reason": self.answer.reason if self.answer is not None else "",
            "sent_s": self.sent_s,
        }


@dataclass
class Pilot:
    """What the page shows and what it sent: updated by Zenoh's callbacks, read by the server's
    threads, under one lock."""

    session: zenoh.Session
    system: str
    site: str = ""
    lock: threading.Lock = field(default_factory=threading.Lock)
    latest: dict[str, tuple[float, Any]] = field(default_factory=dict)  # what -> (arrival [s, wall], message)
    frame: tuple[float, int, bytes] | None = None  # arrival, count, JPEG
    sent: dict[int, Sent] = field(default_factory=dict)
    alerts: list[dict[str, Any]] = field(default_factory=list)
    goals: Goals = field(default_factory=Goals)  # teleop's, started from the telemetry as abyss teleop's
    teleop_sent: int = 0
    _failsafe: str = ""
    _silent: bool = False

    def __post_init__(self) -> None:
        self.panel = site_at(self.site).panel  # the running site's, that commands are checked against

    def start(self) -> list[Any]:
        """Subscribe to what reached shore; the subscribers (keep them)."""
        take = {
            keys.spec("vessel", "telemetry").key(self.system): (Telemetry, self._telemetry),
            keys.mission_key(self.system): (MissionStatus, lambda m: self._keep("mission", m)),
            keys.spec("vessel", "objects").key(self.system): (
                RecognisedObjects,
                lambda m: self._keep("objects", m),
            ),
            keys.spec("vessel", "image").key(self.system): (Image, self._image),
            keys.operator_key(self.system, "ack"): (CommandAck, self._answer),
        }

        def on(cls: Any, handler: Any) -> Any:
            def callback(sample: zenoh.Sample) -> None:
                message = message_of(sample, cls)
                if message is not None:
                    handler(message)

            return callback

        return [self.session.declare_subscriber(k, on(cls, handler)) for k, (cls, handler) in take.items()]

    def _keep(self, what: str, message: Any) -> None:
        with self.lock:
            self.latest[what] = (time.time(), message)

    def _telemetry(self, telemetry: Telemetry) -> None:
        with self.lock:
            self.latest["telemetry"] = (time.time(), telemetry)
            self.goals.start_from(telemetry)
            if telemetry.failsafe != self._failsafe:
                self._alert(f"failsafe: {telemetry.failsafe}" if telemetry.failsafe else "failsafe left")
                self._failsafe = telemetry.failsafe
            if self._silent:
                self._alert("the vessel's telemetry reaches shore again")
                self._silent = False

    def _image(self, image: Image) -> None:
        if image.encoding != "jpeg":
            return
        with self.lock:
            count = self.frame[1] + 1 if self.frame else 1
            self.frame = (time.time(), count, image.data)

    def _answer(self, ack: CommandAck) -> None:
        with self.lock:
            sent = self.sent.get(ack.command_id)
            if sent is None or sent.topic != ack.command or sent.answer is not None:
                return
            sent.answer = ack
            if not ack.accepted:
                self._alert(f"{sent.kind} {sent.text} refused: {ack.reason}")

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
            self.sent[command.command_id] = Sent(command, kind, f"{text} {amount}".strip(), topic, now, now)
        self._put(self.sent[command.command_id])
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
        self.session.put(
            keys.operator_key(self.system, topic), encode(command, self.teleop_sent, time.time())
        )

    def _put(self, sent: Sent) -> None:
        self.session.put(keys.operator_key(self.system, sent.topic), encode(sent.command, 0, time.time()))

    def resend(self) -> None:
        """Commands not answered yet, sent again; the vessel's silence noticed."""
        now = time.time()
        with self.lock:
            due = [
                s for s in self.sent.values() if s.answer is None and now - s.last_sent_s >= RESEND_PERIOD_S
            ]
            for s in due:
                s.last_sent_s = now
            telemetry = self.latest.get("telemetry")
            if telemetry is not None and now - telemetry[0] > SILENT_S and not self._silent:
                self._silent = True
                self._alert(
                    f"no telemetry from the vessel for {now - telemetry[0]:.0f} s (satellite or vessel lost)"
                )
        for s in due:
            self._put(s)

    def state(self) -> dict[str, Any]:
        """What the page shows, each with its age [s]."""
        now = time.time()
        with self.lock:
            shown: dict[str, Any] = {"wall_s": now, "system": self.system}
            for what, (arrived, message) in self.latest.items():
                shown[what] = {"age_s": now - arrived, **_fields(message)}
            if self.frame is not None:
                shown["frame"] = {"age_s": now - self.frame[0], "count": self.frame[1]}
            shown["commands"] = [s.view() for s in sorted(self.sent.values(), key=lambda s: -s.sent_s)][:20]
            shown["alerts"] = list(reversed(self.alerts))
            shown["teleop_sent"] = self.teleop_sent
        return shown

    def jpeg(self) -> bytes | None:
        with self.lock:
            return self.frame[2] if self.frame else None


def _fields(message: Any) -> dict[str, Any]:
    """A message's fields the page reads, as JSON values."""
    if isinstance(message, Telemetry):
        x, y, z = (float(v) for v in message.position_m_world)
        return {
            "position_m_world": [x, y, z],
            "depth_m": -z,
            "heading_rad": message.yaw_rad,
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
    assert isinstance(message, RecognisedObjects)
    return {"names": list(message.names), "method": message.method}


def _handler(pilot: Pilot) -> type[BaseHTTPRequestHandler]:
    class Handler(BaseHTTPRequestHandler):
        def do_GET(self) -> None:
            path = self.path.split("?", 1)[0]
            if path in FILES:
                name, kind = FILES[path]
                self._reply(HTTPStatus.OK, (WEB / name).read_bytes(), kind)
            elif path == "/state":
                self._reply(HTTPStatus.OK, json.dumps(pilot.state()).encode(), "application/json")
            elif path == "/frame.jpg" and (jpeg := pilot.jpeg()) is not None:
                self._reply(HTTPStatus.OK, jpeg, "image/jpeg")
            else:
                self._reply(HTTPStatus.NOT_FOUND, b"not found", "text/plain")

        def do_POST(self) -> None:
            if self.path not in ("/command", "/teleop"):
                self._reply(HTTPStatus.NOT_FOUND, b"not found", "text/plain")
                return
            try:
                asked = json.loads(self.rfile.read(int(self.headers.get("Content-Length", 0))))
                if self.path == "/teleop":
                    pilot.nudge(asked["target"], list(asked["translation_m"]), list(asked["rotation_rad"]))
                    command_id = -1
                else:
                    command_id = pilot.send(
                        str(asked["kind"]), str(asked["value"]), str(asked.get("amount", ""))
                    )
            except (AbyssError, BadInput, KeyError, ValueError, TypeError) as exc:
                self._reply(
                    HTTPStatus.BAD_REQUEST, json.dumps({"error": str(exc)}).encode(), "application/json"
                )
                return
            self._reply(HTTPStatus.OK, json.dumps({"id": command_id}).encode(), "application/json")

        def _reply(self, status: HTTPStatus, body: bytes, kind: str) -> None:
            self.send_response(status)
            self.send_header("Content-Type", kind)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "no-store")
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, format: str, *args: Any) -> None:
            log.debug(format, *args)

    return Handler


class Console:
    """The console served on 127.0.0.1:`port` (0: any free one) over `session`, a session on
    shore's network (`abyss console`'s own, or `abyss up`'s); `url` where; `close()` ends it."""

    def __init__(self, session: zenoh.Session, system: str, port: int, site: str = "") -> None:
        self.pilot = Pilot(session, system, site)
        self.subscribers = self.pilot.start()
        try:
            self.server = ThreadingHTTPServer(("127.0.0.1", port), _handler(self.pilot))
        except OSError as exc:
            self._undeclare()
            raise ConfigError("--console", f"cannot serve on 127.0.0.1:{port}: {exc}") from None
        self.server.daemon_threads = True
        self.url = f"http://127.0.0.1:{self.server.server_address[1]}/"
        self.stop = threading.Event()
        self.threads = [
            threading.Thread(target=self.server.serve_forever, name="console http", daemon=True),
            threading.Thread(target=self._resend, name="console resend", daemon=True),
        ]
        for thread in self.threads:
            thread.start()

    def _resend(self) -> None:
        while not self.stop.wait(0.5):
            self.pilot.resend()

    def _undeclare(self) -> None:
        for subscriber in self.subscribers:
            subscriber.undeclare()

    def close(self) -> None:
        self.stop.set()
        self.server.shutdown()
        self.server.server_close()
        self._undeclare()


def run_console(endpoint: str, system: str, port: int, site: str = "") -> int:
    """`abyss console`: serve the console until interrupted."""
    session = open_session(client_config(endpoint), "abyss console")
    try:
        console = Console(session, system, port, site)
        print(f"abyss console: {console.url} (system {system!r} at {endpoint})", flush=True)
        try:
            threading.Event().wait()
        except KeyboardInterrupt:
            return 0
        finally:
            console.close()
    finally:
        session.close()
    return 0
