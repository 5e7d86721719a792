"""`abyss teleop`: the operator drives the vehicle or the end-effector from a joystick when one
is plugged in, from the keyboard otherwise. Teleoperation writes goals, not velocities: each
key press (or each half second of stick deflection) moves the goal pose by a step and sends
it as a new command through the onshore station, down the satellite and the tether on the
same keys the autonomous side uses. A goal survives a lost or late packet (the onshore
station resends it until onboard answers it); a velocity stream would not.

Intents on the panel go down as one small command each, for the vessel to resolve from the
panel it recognised and onboard to carry out; their answers are printed as they come.

Keys (the vehicle's frame: forward, left, up): w/s forward/back, a/d left/right, r/f up/down,
q/e turn left/right (vehicle) or yaw (end-effector), i/k pitch, u/o roll (end-effector),
Tab switches vehicle/end-effector, Space resends, h help, x or Ctrl-C quits.
Intents on the panel's parts, on the number keys (listed at the start).
"""

from __future__ import annotations

import math
import os
import select
import struct
import sys
import termios
import threading
import time
import tty
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Literal

import numpy as np
import zenoh

from abyss.bus import description
from abyss.bus.session import client_config, message_of, open_session
from abyss.common.errors import BadInput, BusError
from abyss.common.geometry import quat_wxyz_of, rotation_of, rotation_of_rpy, wrap_rad
from abyss.console.access import operator_name
from abyss.console.op import Command, hand_command
from abyss.description.models.panel import Panel, intent_of
from abyss.interface import keys
from abyss.interface.messages import ArmGoal, CommandAck, Intervention, Telemetry, Waypoints, new_id

Target = Literal["vehicle", "arm"]  # what the keys drive: the vehicle's waypoint or the end-effector's goal
# key -> (forward, left, up) [steps], (roll, pitch, yaw) [steps]
KEYMAP: dict[str, tuple[tuple[int, int, int], tuple[int, int, int]]] = {
    "w": ((1, 0, 0), (0, 0, 0)),
    "s": ((-1, 0, 0), (0, 0, 0)),
    "a": ((0, 1, 0), (0, 0, 0)),
    "d": ((0, -1, 0), (0, 0, 0)),
    "r": ((0, 0, 1), (0, 0, 0)),
    "f": ((0, 0, -1), (0, 0, 0)),
    "q": ((0, 0, 0), (0, 0, 1)),
    "e": ((0, 0, 0), (0, 0, -1)),
    "i": ((0, 0, 0), (0, 1, 0)),
    "k": ((0, 0, 0), (0, -1, 0)),
    "u": ((0, 0, 0), (1, 0, 0)),
    "o": ((0, 0, 0), (-1, 0, 0)),
}
INTENT_KEYS = "1234567890"  # the number keys, given to the site's parts in turn (intent_keys)


def intent_keys(panel: Panel) -> dict[str, tuple[str, str]]:
    """Key -> an intent on a part of the running site's panel and its amount (`abyss op valve|lever`):
    each valve turned by +90 deg, then each by -90 deg, then each lever up and down, on 1-9 and 0
    while they last (the shipped panel's: 1/2/3 turn valve_0/1/2 by +90 deg, 4/5/6 by -90 deg,
    7/8 throw lever_0 up/down, 9/0 lever_1)."""
    valves, levers = list(panel.valves), list(panel.levers)
    intents = [(v, "90") for v in valves] + [(v, "-90") for v in valves]
    intents += [(lever, stop) for lever in levers for stop in ("up", "down")]
    return dict(zip(INTENT_KEYS, intents, strict=False))


JS_EVENT = struct.Struct("<IhBB")  # Linux joystick API: time [ms], value, type, number
JS_BUTTON, JS_AXIS, JS_INIT = 0x01, 0x02, 0x80
JOYSTICK_SEND_PERIOD_S = 0.5
JOYSTICK_DEADBAND = 0.1


@dataclass
class Goals:
    """The goal poses being driven, started from the vehicle's telemetry."""

    vehicle: np.ndarray | None = None  # x, y, z [m, world], yaw [rad]
    ee_position_m_world: np.ndarray | None = None
    ee_rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    yaw_rad: float = 0.0  # the vehicle's heading: the frame of the steps

    def start_from(self, t: Telemetry) -> None:
        self.yaw_rad = t.yaw_rad
        if self.vehicle is None:
            self.vehicle = np.r_[t.position_m_world, t.yaw_rad]
        if self.ee_position_m_world is None:
            self.ee_position_m_world = np.array(t.ee_position_m_world)
            self.ee_rotation = rotation_of(t.ee_orientation_wxyz_world)

    def move(self, target: Target, translation: np.ndarray, rotation_rad: np.ndarray) -> Waypoints | ArmGoal:
        """Move one goal by steps in the vehicle's heading frame; the command to send."""
        assert self.vehicle is not None and self.ee_position_m_world is not None
        heading = rotation_of_rpy(0.0, 0.0, self.yaw_rad)
        command_id = new_id()
        if target == "vehicle":
            self.vehicle[:3] += heading @ translation
            self.vehicle[3] = wrap_rad(self.vehicle[3] + rotation_rad[2])
            return Waypoints(command_id, self.vehicle[None, :].copy())
        self.ee_position_m_world = self.ee_position_m_world + heading @ translation
        turn = heading @ rotation_of_rpy(*rotation_rad) @ heading.T  # about the heading frame's axes
        self.ee_rotation = turn @ self.ee_rotation
        return ArmGoal(command_id, self.ee_position_m_world.copy(), quat_wxyz_of(self.ee_rotation))


class Teleop:
    def __init__(self, endpoint: str, system: str, step_m: float, step_rad: float, out: IO[str]) -> None:
        self.system = system
        self.step_m, self.step_rad = step_m, step_rad
        self.out = out
        self.goals = Goals()
        self.target: Target = "vehicle"
        self.by = operator_name("abyss teleop")
        self.lock = threading.Lock()
        self.session = open_session(client_config(endpoint), "abyss teleop")
        try:  # the running site's panel, whose parts the number keys work
            self.intent_keys = intent_keys(description.fetch(self.session, system).panel)
        except BusError:
            self.session.close()
            raise
        self.subscriber = self.session.declare_subscriber(
            keys.spec("vessel", "telemetry").key(system), self._on_telemetry
        )
        self.acks = self.session.declare_subscriber(keys.operator_key(system, "ack"), self._on_ack)
        self.intents: dict[int, str] = {}  # command id -> what was asked, till answered
        self.sent = 0

    def _on_ack(self, sample: zenoh.Sample) -> None:
        ack = message_of(sample, CommandAck)
        if ack is None:
            return
        with self.lock:
            asked = self.intents.pop(ack.command_id, None)
        if asked is not None:
            self.say(f"{asked}: {'taken by onboard' if ack.accepted else 'refused: ' + ack.reason}")

    def _on_telemetry(self, sample: zenoh.Sample) -> None:
        message = message_of(sample, Telemetry)
        if message is None:
            return
        with self.lock:
            self.goals.start_from(message)

    def say(self, text: str) -> None:
        self.out.write(text + "\r\n")
        self.out.flush()

    def ready(self) -> bool:
        with self.lock:
            return self.goals.vehicle is not None

    def press(self, key: str) -> bool:
        """Handle one key; False to quit."""
        if key in ("x", "\x03", "\x04"):
            return False
        if key == "\t":
            self.target = "arm" if self.target == "vehicle" else "vehicle"
            self.say(f"driving the {'end-effector' if self.target == 'arm' else 'vehicle'}")
        elif key == "h":
            self.say(__doc__.split("\n\n")[-1].strip().replace("\n", "\r\n") if __doc__ else "")
        elif key in self.intent_keys:
            self.intend(*self.intent_keys[key])
        elif key in KEYMAP or key == " ":
            translation, rotation = KEYMAP.get(key, ((0, 0, 0), (0, 0, 0)))
            self.nudge(np.array(translation, float) * self.step_m, np.array(rotation, float) * self.step_rad)
        else:
            self.say(f"unknown key {key!r}; h for help")
        return True

    def nudge(self, translation_m: np.ndarray, rotation_rad: np.ndarray) -> None:
        if not self.ready():
            self.say("no telemetry from the vessel yet: nothing to start the goal from")
            return
        with self.lock:
            command = self.goals.move(self.target, translation_m, rotation_rad)
        topic = "waypoints" if isinstance(command, Waypoints) else "arm"
        if not self._hand(topic, command, teleop=True):
            return
        if isinstance(command, Waypoints):
            x, y, z, yaw = command.waypoints[0]
            self.say(f"vehicle goal {x:.2f} {y:.2f} {z:.2f} m, yaw {math.degrees(yaw):.0f} deg")
        else:
            x, y, z = command.position_m_world
            self.say(f"end-effector goal {x:.3f} {y:.3f} {z:.3f} m")

    def intend(self, part: str, amount: str) -> None:
        command = Intervention(new_id(), part, *intent_of(amount))
        asked = f"{part} {'to ' + amount if command.to else 'turn ' + amount + ' deg'}"
        with self.lock:
            self.intents[command.command_id] = asked
        if self._hand("intervene", command):
            self.say(f"intent {asked} sent")

    def _hand(self, topic: str, command: Command, teleop: bool = False) -> bool:
        """Hand `command` to shore (which resends it until onboard answers); whether it took it."""
        try:
            hand_command(self.session, self.system, topic, command, self.by, teleop)
        except (BusError, BadInput) as exc:
            self.say(f"not sent: {exc}")
            return False
        self.sent += 1
        return True

    def close(self) -> None:
        self.acks.undeclare()
        self.subscriber.undeclare()
        self.session.close()


def keyboard(teleop: Teleop, stdin: IO[str]) -> None:
    fd = stdin.fileno()
    saved = termios.tcgetattr(fd) if os.isatty(fd) else None
    if saved is not None:
        tty.setcbreak(fd)
    try:
        while True:
            readable, _, _ = select.select([fd], [], [], 0.2)
            if not readable:
                continue
            key = os.read(fd, 1).decode(errors="replace")
            if not key or not teleop.press(key):
                return
    finally:
        if saved is not None:
            termios.tcsetattr(fd, termios.TCSADRAIN, saved)


def joystick(teleop: Teleop, path: Path, speed_mps: float, rate_radps: float) -> None:
    """Sticks: axis 0 left/right, 1 forward/back, 2 yaw, 3 up/down (as most gamepads map them);
    button 0 switches vehicle/end-effector. The goal moves at the deflection times the speed."""
    axes = np.zeros(4)
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    keys_fd = [sys.stdin.fileno()] if sys.stdin.isatty() else []  # x quits here too
    last_s = time.monotonic()
    try:
        while True:
            readable, _, _ = select.select([fd, *keys_fd], [], [], 0.05)
            if keys_fd and keys_fd[0] in readable and not teleop.press(os.read(keys_fd[0], 1).decode()):
                return
            if fd in readable:
                data = os.read(fd, JS_EVENT.size * 64)
                if not data:
                    return  # unplugged
                for i in range(0, len(data) - JS_EVENT.size + 1, JS_EVENT.size):
                    _, value, kind, number = JS_EVENT.unpack_from(data, i)
                    if kind & ~JS_INIT == JS_AXIS and number < len(axes):
                        deflection = value / 32767.0
                        axes[number] = deflection if abs(deflection) > JOYSTICK_DEADBAND else 0.0
                    elif kind & ~JS_INIT == JS_BUTTON and number == 0 and value == 1 and not kind & JS_INIT:
                        teleop.press("\t")
            now = time.monotonic()
            if now - last_s >= JOYSTICK_SEND_PERIOD_S:
                dt, last_s = now - last_s, now
                if axes.any():
                    teleop.nudge(
                        np.array([-axes[1], -axes[0], -axes[3]]) * speed_mps * dt,
                        np.array([0.0, 0.0, -axes[2]]) * rate_radps * dt,
                    )
    finally:
        os.close(fd)


def run_teleop(endpoint: str, system: str, step_m: float, step_deg: float, joystick_path: Path | None) -> int:
    """`abyss teleop`, its number keys on the running system's panel (its description)."""
    if joystick_path is None and Path("/dev/input/js0").exists():
        joystick_path = Path("/dev/input/js0")
    teleop = Teleop(endpoint, system, step_m, math.radians(step_deg), sys.stdout)
    source = f"the joystick {joystick_path}" if joystick_path else "the keyboard"
    teleop.say(f"abyss teleop: system {system} at {endpoint}, driving the vehicle from {source}; h for help")
    teleop.say(
        "intents: " + ", ".join(f"{k} {part} {amount}" for k, (part, amount) in teleop.intent_keys.items())
    )
    try:
        deadline = time.monotonic() + 10.0
        while not teleop.ready() and time.monotonic() < deadline:
            time.sleep(0.1)
        if not teleop.ready():
            teleop.say("waiting for the vessel's telemetry (is the system up?)")
        if joystick_path is not None:
            joystick(teleop, joystick_path, speed_mps=step_m, rate_radps=math.radians(step_deg))
        else:
            keyboard(teleop, sys.stdin)
    except KeyboardInterrupt:
        pass
    finally:
        teleop.close()
    teleop.say(f"abyss teleop: {teleop.sent} goals sent")
    return 0
