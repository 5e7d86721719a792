"""The simulation as ArduPilot's JSON physics backend (`abyss sitl`), held to the protocol as
SIM_JSON.cpp and its readme write it, by a client of our own in ArduPilot's place (no ArduSub
build here: docs/mavlink.md says why): servo packets with ArduPilot's magic, frame rate and count
in, one JSON line per frame out with the fields and the vector format its parser reads; the frame
count kept in lockstep (a resend answered unchanged, a count gone back a restart); the BlueROV2
Heavy flown by its eight motors as ArduSub's vectored 6-DoF frame drives them: forward, up and
yaw right go where ArduSub means them, in its frames (north-east-down, forward-right-down)."""

from __future__ import annotations

import json
import re
import socket
import subprocess
import sys
from collections.abc import Iterator

import numpy as np
import pytest

from abyss.common.errors import ConfigError
from abyss.description.robot import ROBOTS_DIR, robot_at
from abyss.mavlink.sitl_json import VECTORED_6DOF, ServoPacket, frame_thrusters

ROBOT = ROBOTS_DIR / "bluerov2_heavy_alpha5"
RATE_HZ = 400
NUMBER = r"-?[\d.e+-]+"
VECTOR = re.compile(rf"\[{NUMBER}, {NUMBER}, {NUMBER}\]")  # SIM_JSON reads "[%f, %f, %f]"
QUATERNION = re.compile(rf"\[{NUMBER}, {NUMBER}, {NUMBER}, {NUMBER}\]")  # and "[%f, %f, %f, %f]"
ROLL, PITCH, YAW, THROTTLE, FORWARD, LATERAL = range(6)


class ArduPilotSide:
    """What SIM_JSON.cpp does: a servo packet out per frame, the line back parsed as it parses it."""

    def __init__(self, port: int) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.settimeout(5.0)
        self.port = port
        self.count = 0

    def frame(self, pwm: list[int], count: int | None = None) -> dict[str, object]:
        if count is None:
            self.count += 1
        packet = ServoPacket(RATE_HZ, self.count if count is None else count, tuple(pwm)).pack()
        self.sock.sendto(packet, ("127.0.0.1", self.port))
        line = self.sock.recvfrom(4096)[0].decode()
        assert line.startswith("\n") and line.endswith("\n")  # preceded and terminated by a newline
        for section, key in (
            ("imu", "gyro"),
            ("imu", "accel_body"),
            ("position", ""),
            ("velocity", ""),
            ("quaternion", ""),
        ):
            text = line[line.index(f'"{section}"') :]
            if key:
                text = text[text.index(f'"{key}"') :]
            assert (QUATERNION if section == "quaternion" else VECTOR).match(text[text.index("[") :]), (
                section,
                key,
            )
        return dict(json.loads(line))

    def fly(self, inputs: dict[int, float], seconds: float) -> dict[str, object]:
        """ArduSub's mixing of pilot inputs (each in [-1, 1]) over its frame's factors, as PWM."""
        outputs = [sum(f[axis] * value for axis, value in inputs.items()) for f in VECTORED_6DOF]
        pwm = [round(1500 + 400 * max(-1.0, min(1.0, o))) for o in outputs] + [1500] * 8
        state: dict[str, object] = {}
        for _ in range(round(seconds * RATE_HZ)):
            state = self.frame(pwm)
        return state


@pytest.fixture(scope="module")
def sitl() -> Iterator[ArduPilotSide]:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    process = subprocess.Popen(
        [sys.executable, "-m", "abyss.cli", "sitl", "--robot", str(ROBOT), "--port", str(port)],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    assert process.stdout is not None
    said = process.stdout.readline()
    assert (
        "ArduPilot's JSON physics" in said
        and "motors 1-8 are its thrusters thr_fr, thr_fl, thr_rr, thr_rl" in said
    ), said
    side = ArduPilotSide(port)
    try:
        yield side
    finally:
        side.sock.close()
        process.terminate()
        out, _ = process.communicate(timeout=20)
        assert process.returncode == 0, out
        assert re.search(r"\d+ frames, 0 lost, 1 resent, 1 restarts", out), out


def test_the_frames_match_the_heavys_thrusters() -> None:
    mapping = frame_thrusters(robot_at(str(ROBOT)))
    names = robot_at(str(ROBOT)).marine.thrusters.names
    assert [names[j] for j, _ in mapping] == [
        "thr_fr",
        "thr_fl",
        "thr_rr",
        "thr_rl",
        "thr_vfr",
        "thr_vfl",
        "thr_vrr",
        "thr_vrl",
    ]
    with pytest.raises(ConfigError) as error:  # the work-class ROV's six thrusters make no such frame
        frame_thrusters(robot_at(""))
    assert error.value.field == "simulation.robot" and "motor" in error.value.reason


def test_a_frame_is_one_step_of_its_rate_and_at_rest_the_imu_reads_gravity(sitl: ArduPilotSide) -> None:
    first = sitl.fly({}, 0.05)
    later = sitl.fly({}, 1.0)
    assert float(later["timestamp"]) - float(first["timestamp"]) == pytest.approx(1.0, abs=0.003)
    accel = np.array(later["imu"]["accel_body"])  # type: ignore[index]
    assert accel == pytest.approx([0.0, 0.0, -9.81], abs=0.3)  # forward-right-down: gravity's reaction up
    assert np.linalg.norm(later["quaternion"]) == pytest.approx(1.0)  # type: ignore[arg-type]


def test_ardusubs_forward_up_and_yaw_right_go_where_it_means_them(sitl: ArduPilotSide) -> None:
    start = sitl.fly({}, 0.01)
    forward = sitl.fly({FORWARD: 0.5}, 2.0)
    velocity = np.array(forward["velocity"])  # north-east-down; the vehicle faces the site's x: east
    assert velocity[1] > 0.1 and abs(velocity[0]) < 0.05, velocity
    sitl.fly({}, 2.0)
    before = np.array(sitl.fly({}, 0.01)["position"])
    up = sitl.fly({THROTTLE: 0.5}, 2.0)
    assert np.array(up["position"])[2] < before[2] - 0.05  # down decreased: it rose
    turning = sitl.fly({YAW: 0.5}, 1.5)
    assert np.array(turning["imu"]["gyro"])[2] > 0.05  # type: ignore[index]  # yaw right: clockwise, positive down
    assert float(turning["timestamp"]) > float(start["timestamp"])


def test_a_resend_is_answered_unchanged_and_a_count_gone_back_restarts_the_vehicle(
    sitl: ArduPilotSide,
) -> None:
    first = sitl.fly({}, 0.01)
    again = sitl.frame([1500] * 16, count=sitl.count)  # ArduPilot's resend after a silence: the same count
    assert again["timestamp"] == first["timestamp"]
    sitl.count = 0
    restarted = sitl.fly({}, 0.0025)  # frame 1 again: ArduPilot restarted
    assert float(restarted["timestamp"]) < 0.01
    sitl.sock.sendto(b"not a servo packet", ("127.0.0.1", sitl.port))  # dropped, counted, not answered
    assert float(sitl.fly({}, 0.0025)["timestamp"]) < 0.02
