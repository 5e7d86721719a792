"""`abyss teleop` as an operator runs it: in a pseudo terminal (keys) and on a joystick device
(a FIFO fed with Linux joystick events), against a test that plays the vessel's telemetry and
watches the operator keys over real Zenoh."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import zenoh
from conftest import ROOT

from abyss.bus import description
from abyss.bus.session import Bus, open_session, zenoh_config
from abyss.common.ports import free_port
from abyss.console.teleop import JS_AXIS, JS_EVENT
from abyss.description.robot import robot_at
from abyss.description.site import site_at
from abyss.interface import keys
from abyss.interface.messages import (
    TOOL_COMMANDS,
    ArmGoal,
    CommandAck,
    Intervention,
    Message,
    Telemetry,
    Waypoints,
    decode,
    encode,
)
from abyss.interface.system_description import description_payload

pytestmark = pytest.mark.timeout(90)
SYSTEM = "e2e-teleop"
POSITION = np.array([3.3, 0.0, -7.9])
EE_POSITION = np.array([4.86, 0.0, -8.35])


class Vessel:
    """Publishes telemetry as the vessel does, serves the running system's description as a
    station's shell does (the shipped pair's), takes the operator's commands as the onshore
    station does; records what the operator's tools send."""

    def __init__(self) -> None:
        self.port = free_port()
        self.session = open_session(zenoh_config(listen=[f"tcp/127.0.0.1:{self.port}"]), "test vessel")
        self.commands: list[Message] = []
        self.lock = threading.Lock()
        self.stop = threading.Event()
        self.subscriber = self.session.declare_subscriber(keys.operator_key(SYSTEM, "*"), self._on_command)
        payload = description_payload(SYSTEM, robot_at(""), site_at(""))
        self.description = description.serve(self.session, SYSTEM, "vessel", payload)
        self.onshore = Bus(SYSTEM, "onshore", self.session)  # takes the commands, puts them out as taken
        for topic, message in TOOL_COMMANDS:
            self.onshore.take_key(keys.operator_key(SYSTEM, topic), message)
        self.thread = threading.Thread(target=self._telemetry, daemon=True)
        self.thread.start()

    def _on_command(self, sample: zenoh.Sample) -> None:
        message = decode(str(sample.key_expr), sample.payload.to_bytes()).message
        if isinstance(message, CommandAck):  # its own answers, on the operator's ack key
            return
        with self.lock:
            self.commands.append(message)

    def _telemetry(self) -> None:
        key, seq = keys.spec("vessel", "telemetry").key(SYSTEM), 0
        while not self.stop.wait(0.2):
            t = Telemetry(
                POSITION,
                0.0,
                "reached",
                1,
                3,
                3,
                np.zeros(3),
                0.0,
                "idle",
                -1,
                np.zeros(3),
                0.0,
                EE_POSITION,
                np.array([1.0, 0, 0, 0]),
                np.zeros(6),
                "",
                0,
                10.0,
            )
            self.session.put(key, encode(t, seq, time.time()))
            seq += 1

    def wait_for(self, count: int, timeout_s: float = 10.0) -> list[Message]:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with self.lock:
                if len(self.commands) >= count:
                    return list(self.commands)
            time.sleep(0.05)
        raise AssertionError(f"expected {count} commands, got {self.commands}")

    def close(self) -> None:
        self.stop.set()
        self.thread.join()
        self.subscriber.undeclare()
        self.onshore.close()
        self.description.undeclare()
        self.session.close()


@pytest.fixture
def vessel() -> Iterator[Vessel]:
    v = Vessel()
    yield v
    v.close()


def teleop(vessel: Vessel, *args: str, **streams: object) -> subprocess.Popen[bytes]:
    return subprocess.Popen(
        [
            sys.executable,
            "-m",
            "abyss.cli",
            "teleop",
            "--connect",
            f"tcp/127.0.0.1:{vessel.port}",
            "--system",
            SYSTEM,
            *args,
        ],
        cwd=ROOT,
        start_new_session=True,
        **streams,
    )  # type: ignore[call-overload]


def test_keys_in_a_pseudo_terminal_move_the_goals(vessel: Vessel) -> None:
    master, slave = os.openpty()
    process = teleop(vessel, stdin=slave, stdout=slave, stderr=slave)
    os.close(slave)
    output = bytearray()

    def read() -> None:
        while True:
            try:
                chunk = os.read(master, 1024)
            except OSError:
                return
            if not chunk:
                return
            output.extend(chunk)

    reader = threading.Thread(target=read, daemon=True)
    reader.start()

    def expect(text: str) -> None:
        deadline = time.monotonic() + 15
        while text.encode() not in output and time.monotonic() < deadline:
            time.sleep(0.05)
        assert text.encode() in output, output.decode(errors="replace")

    try:
        expect("from the keyboard")
        time.sleep(0.5)  # telemetry reached it: the goal starts from the vehicle
        os.write(master, b"w")
        first = vessel.wait_for(1)[-1]
        assert isinstance(first, Waypoints)
        np.testing.assert_allclose(first.waypoints, [[3.4, 0.0, -7.9, 0.0]], atol=1e-9)
        os.write(master, b"q")
        turned = vessel.wait_for(2)[-1]
        assert isinstance(turned, Waypoints) and turned.waypoints[0, 3] == pytest.approx(np.radians(5))
        assert turned.command_id != first.command_id
        os.write(master, b"\t")
        expect("driving the end-effector")
        os.write(master, b"r")
        arm = vessel.wait_for(3)[-1]
        assert isinstance(arm, ArmGoal)
        np.testing.assert_allclose(arm.position_m_world, EE_POSITION + np.array([0, 0, 0.1]), atol=1e-9)
        os.write(master, b"z")
        expect("unknown key 'z'")
        os.write(master, b"2")  # an intent: one small command, answered on shore's ack key
        intent = vessel.wait_for(4)[-1]
        assert isinstance(intent, Intervention) and intent.target == "valve_1"
        assert intent.turn_rad == pytest.approx(np.radians(90)) and intent.to == ""
        refusal = CommandAck(intent.command_id, "intervene", "valve_1 is at 90 deg already")
        vessel.session.put(keys.operator_key(SYSTEM, "ack"), encode(refusal, 0, time.time()))
        expect("valve_1 turn 90 deg: refused: valve_1 is at 90 deg already")
        os.write(master, b"8")
        lever = vessel.wait_for(5)[-1]
        assert isinstance(lever, Intervention) and (lever.target, lever.to) == ("lever_0", "down")
        os.write(master, b"x")
        assert process.wait(timeout=15) == 0
        expect("5 goals sent")
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
        os.close(master)


def test_a_joystick_drives_the_vehicle_forward(vessel: Vessel, tmp_path: Path) -> None:
    device = tmp_path / "js0"
    os.mkfifo(device)
    process = teleop(
        vessel,
        "--joystick",
        str(device),
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
    )
    try:
        with device.open("wb", buffering=0) as js:
            js.write(JS_EVENT.pack(0, -32767, JS_AXIS, 1))  # left stick fully forward
            commands = vessel.wait_for(2, timeout_s=20)
            js.write(JS_EVENT.pack(0, 0, JS_AXIS, 1))
        output = process.communicate(timeout=15)[0].decode()
        assert process.returncode == 0, output  # the device went away
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()
    goals = [c for c in commands if isinstance(c, Waypoints)]
    assert len(goals) >= 2 and goals[-1].waypoints[0, 0] > goals[0].waypoints[0, 0] > POSITION[0]
    np.testing.assert_allclose(goals[-1].waypoints[0, 1:], [0.0, -7.9, 0.0], atol=1e-9)
    assert "from the joystick" in output and "goals sent" in output
