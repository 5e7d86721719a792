"""`abyss op`: one operator command from the command line. It goes to the onshore station on
shore's own network, down the satellite and the tether to onboard, which checks it and answers
with its fate; the answer comes back the same way and is printed. Text that does not parse is
refused here, before anything is sent."""

from __future__ import annotations

import json
import math
import threading
import time

import numpy as np
import zenoh

from abyss.bus import description
from abyss.bus.session import client_config, message_of, open_session
from abyss.common.errors import BadInput, BusError, ConfigError
from abyss.common.geometry import quat_wxyz_of, rotation_of_rpy
from abyss.console.access import operator_name
from abyss.description.models.panel import Panel, intent_of
from abyss.interface import keys
from abyss.interface.messages import (
    OPERATOR_MODES,
    ArmGoal,
    CommandAck,
    Intervention,
    OperatorMode,
    Waypoints,
    encode,
    new_id,
)

HANDOVER_S = 5.0  # how long a tool waits for the onshore station to take its command
HANDOVER_POLL_S = 0.1  # how often it asks again while no onshore station answers (none took it)


def _numbers(field: str, text: str, count: int, names: str) -> list[float]:
    parts = [p.strip() for p in text.split(",")]
    try:
        values = [float(p) for p in parts]
    except ValueError:
        raise ConfigError(field, f"{text.strip()!r} is not {count} numbers {names}") from None
    if len(values) != count or not all(np.isfinite(values)):
        raise ConfigError(field, f"{text.strip()!r} has {len(values)} values; expected {count}: {names}")
    return values


def parse_waypoints(text: str) -> np.ndarray:
    """'x,y,z,yaw; x,y,z,yaw; ...' [m, m, m, rad, world] -> rows."""
    rows = [row for row in text.split(";") if row.strip()]
    if not rows:
        raise ConfigError("waypoints", "no waypoint given; expected 'x,y,z,yaw; ...' [m, rad]")
    return np.array([_numbers(f"waypoint {i}", row, 4, "x,y,z,yaw [m, rad]") for i, row in enumerate(rows)])


def parse_arm(text: str) -> tuple[np.ndarray, np.ndarray]:
    """'x,y,z,roll,pitch,yaw' [m, rad, world] -> position, quaternion (w, x, y, z)."""
    x, y, z, roll, pitch, yaw = _numbers("arm", text, 6, "x,y,z,roll,pitch,yaw [m, rad]")
    return np.array([x, y, z]), quat_wxyz_of(rotation_of_rpy(roll, pitch, yaw))


Command = Waypoints | ArmGoal | OperatorMode | Intervention  # what `abyss op` sends
UNNAMED = "an operator's tool that gave no name"


def hand_command(
    session: zenoh.Session, system: str, topic: str, command: Command, by: str, teleop: bool = False
) -> None:
    """Hand `command` to the onshore station on operator/`topic`, signed with who sent it (`by`)
    and whether it is a teleop goal, and wait until it takes it: shore then resends it down the
    satellite until onboard answers (the one place that resends) and puts it on the key as taken,
    so that every console on shore shows it and its sender. While no onshore station is there to
    answer (one starting), it asks again: nothing was taken, so nothing is sent twice. BusError
    where none answers within HANDOVER_S; BadInput with shore's reason where it refuses it."""
    signature = json.dumps({"by": by, "teleop": teleop}).encode()
    key, payload = keys.operator_key(system, topic), encode(command, 0, time.time())
    deadline = time.monotonic() + HANDOVER_S
    while True:
        for reply in session.get(key, payload=payload, attachment=signature, timeout=HANDOVER_S):
            if reply.ok is not None:
                return
            if reply.err is not None:
                raise BadInput(f"the onshore station refused it: {reply.err.payload.to_bytes().decode()}")
        if time.monotonic() >= deadline:
            raise BusError(
                f"no onshore station of system {system!r} took the command within {HANDOVER_S:g} s"
            )
        time.sleep(HANDOVER_POLL_S)


def sender_of(sample: zenoh.Sample) -> tuple[str, bool]:
    """Who sent the command in `sample` and whether it is a teleop goal (hand_command's signature)."""
    try:
        signature = json.loads(sample.attachment.to_bytes()) if sample.attachment is not None else {}
        return str(signature.get("by") or UNNAMED), bool(signature.get("teleop", False))
    except (ValueError, AttributeError):
        return UNNAMED, False


def text_of(command: Command) -> str:
    """A command as `abyss op` takes it (`mode hold`, `waypoints 5,0,-10,0`, `valve valve_1 90`)."""
    if isinstance(command, OperatorMode):
        return command.mode
    if isinstance(command, Waypoints):
        return "; ".join(",".join(f"{v:g}" for v in row.round(3)) for row in command.waypoints)
    if isinstance(command, Intervention):
        return f"{command.target} {command.to or f'{math.degrees(command.turn_rad):g}'}"
    return ",".join(f"{v:g}" for v in command.position_m_world.round(3))


INTENTS = ("valve", "lever")  # `abyss op valve NAME --turn DEG`, `abyss op lever NAME --to STOP`


def command_of(
    kind: str, text: str, command_id: int, amount: str = "", panel: Panel | None = None
) -> Command:
    """The command `abyss op KIND TEXT` sends; `amount`: a valve's turn [deg] or a lever's stop;
    `panel`: the running site's, which the part is checked against (the vessel checks it again)."""
    if kind in INTENTS:
        try:
            if panel is not None and panel.part_kind(text) != kind:
                raise BadInput(f"{text} is a {panel.part_kind(text)}, not a {kind}")
            turn_rad, stop = intent_of(amount)
            if bool(stop) != (kind == "lever"):
                how = "thrown up or down" if kind == "lever" else "turned by an angle in [-180, 180] deg"
                raise BadInput(f"a {kind} is {how}, not {amount!r}")
            return Intervention(command_id, text, turn_rad, stop)
        except BadInput as exc:
            raise ConfigError(kind, str(exc)) from None
    if kind == "waypoints":
        return Waypoints(command_id, parse_waypoints(text))
    if kind == "arm":
        return ArmGoal(command_id, *parse_arm(text))
    if text not in OPERATOR_MODES:
        raise ConfigError("mode", f"{text!r} not one of {', '.join(OPERATOR_MODES)}")
    return OperatorMode(command_id, text)


def send(
    session: zenoh.Session, system: str, command: Command, topic: str, timeout_s: float
) -> CommandAck | None:
    """Hand `command` to the onshore station and wait for onboard's answer; None if none came
    within `timeout_s` (BusError where shore did not take it)."""
    answered = threading.Event()
    answer: list[CommandAck] = []

    def on_ack(sample: zenoh.Sample) -> None:
        ack = message_of(sample, CommandAck)
        if ack is not None and ack.command_id == command.command_id and ack.command == topic:
            answer.append(ack)
            answered.set()

    subscriber = session.declare_subscriber(keys.operator_key(system, "ack"), on_ack)
    try:
        hand_command(session, system, topic, command, operator_name("abyss op"))
        answered.wait(timeout_s)
    finally:
        subscriber.undeclare()
    return answer[0] if answer else None


def run_op(endpoint: str, system: str, kind: str, text: str, timeout_s: float, amount: str = "") -> int:
    """`abyss op`: the command checked against the running system's panel (its description),
    handed to shore, and onboard's answer printed."""
    session = open_session(client_config(endpoint), "abyss op")
    try:
        running = description.fetch(session, system)
        try:
            command = command_of(kind, text, new_id(), amount, running.panel)
        except BadInput as exc:  # numbers the message refuses (out of range)
            raise ConfigError(kind, str(exc)) from None
        topic = "intervene" if kind in INTENTS else kind
        ack = send(session, system, command, topic, timeout_s)
    finally:
        session.close()
    if ack is None:
        print(
            f"abyss op: no answer from onboard within {timeout_s:g} s (is system {system!r} running "
            f"with shore at {endpoint}?)"
        )
        return 1
    if not ack.accepted:
        by = "" if kind in INTENTS else " by onboard"  # an intent the vessel cannot resolve, it refuses
        print(f"{kind} command {ack.command_id}: refused{by}: {ack.reason}")
        return 1
    print(f"{kind} command {ack.command_id}: taken by onboard")
    return 0
