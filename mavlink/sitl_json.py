"""ArduPilot's JSON physics backend (libraries/SITL/SIM_JSON.cpp and its examples/JSON/readme.md;
the protocol carries over, the code does not), served from the simulation's World, so that a
team's own ArduSub build (`sim_vehicle.py -v ArduSub --model JSON`, or `ardusub --model JSON:HOST`)
flies on abyss's physics.

ArduPilot sends its servo outputs on UDP to port 9002: a little-endian packet of a magic (18458:
16 channels; 29569: 32), the frame rate [Hz], a frame count and the PWM [us]; the backend steps its
physics by one frame and answers the sender with one line of JSON: the physics time, the IMU (the
gyro's rates and the accelerometer's specific force, forward-right-down), the position and
velocity north-east-down from the site's origin, and the attitude as a quaternion. The frame count
keeps the two in lockstep: a count seen again is ArduPilot's resend after a silence, answered with
the state unchanged; a count gone back is ArduPilot restarted, and the vehicle is put back at its
start; a count skipped is frames lost, stepped as one.

The servo channels are ArduSub's motors in its frame's order: `frame_thrusters` finds, for each
motor of the vectored 6-DoF frame (the BlueROV2 Heavy's, FRAME_CONFIG 2), the robot's thruster
whose wrench has the signs of the motor's factors (AP_Motors6DOF), and whether its positive
thrust is the motor's positive output; a PWM of 1100-1900 us (1500 neutral) commands the thrust
linearly between the thruster's reverse and forward maxima, the rotor's lag and dead band the
thruster model's own."""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass

import numpy as np

from abyss.common.errors import BadInput, ConfigError
from abyss.common.geometry import quat_wxyz_of, rotation_of
from abyss.description.robot import Robot
from abyss.mavlink.geodesy import Geodesy

PORT = 9002  # where ArduPilot's JSON backend sends its servo outputs
MAGIC_16, MAGIC_32 = 18458, 29569
HEADER = struct.Struct("<HHI")
PWM_NEUTRAL_US, PWM_SPAN_US = 1500.0, 400.0  # ArduSub's MOT_PWM_MIN/MAX: 1100 and 1900
GRAVITY_MPS2 = 9.80665
# AP_Motors6DOF's SUB_FRAME_VECTORED_6DOF, motors 1-8: roll, pitch, yaw, throttle, forward, lateral
VECTORED_6DOF = (
    (0, 0, 1, 0, -1, 1),
    (0, 0, -1, 0, -1, -1),
    (0, 0, -1, 0, 1, 1),
    (0, 0, 1, 0, 1, -1),
    (1, -1, 0, -1, 0, 0),
    (-1, -1, 0, -1, 0, 0),
    (1, 1, 0, -1, 0, 0),
    (-1, 1, 0, -1, 0, 0),
)
FLU_TO_FRD = np.diag([1.0, -1.0, -1.0])


@dataclass(frozen=True)
class ServoPacket:
    frame_rate_hz: int
    frame_count: int
    pwm_us: tuple[int, ...]

    @staticmethod
    def parse(data: bytes) -> ServoPacket:
        """BadInput naming what is wrong for anything but ArduPilot's packet."""
        if len(data) < HEADER.size:
            raise BadInput(f"JSON backend: {len(data)} bytes, a servo packet has at least {HEADER.size}")
        magic, rate, count = HEADER.unpack_from(data)
        channels = {MAGIC_16: 16, MAGIC_32: 32}.get(magic)
        if channels is None:
            raise BadInput(
                f"JSON backend: magic {magic}, ArduPilot's are {MAGIC_16} (16 channels) and {MAGIC_32} (32)"
            )
        if len(data) != HEADER.size + 2 * channels:
            raise BadInput(
                f"JSON backend: {len(data)} bytes, magic {magic} means {HEADER.size + 2 * channels}"
            )
        if rate <= 0:
            raise BadInput("JSON backend: a frame rate of 0 Hz")
        return ServoPacket(rate, count, struct.unpack_from(f"<{channels}H", data, HEADER.size))

    def pack(self) -> bytes:
        """As ArduPilot sends it (16 or 32 channels): for a client in ArduPilot's place."""
        magic = MAGIC_16 if len(self.pwm_us) == 16 else MAGIC_32
        return HEADER.pack(magic, self.frame_rate_hz, self.frame_count) + struct.pack(
            f"<{len(self.pwm_us)}H", *self.pwm_us
        )


def frame_thrusters(robot: Robot) -> list[tuple[int, float]]:
    """For each motor of ArduSub's vectored 6-DoF frame, the robot's thruster (its index) and the
    sign of its thrust for the motor's positive output; ConfigError where the robot's thrusters
    do not make that frame."""
    allocation = robot.allocation  # (6, n): surge, sway, heave, roll, pitch, yaw per newton, forward-left-up
    frd = np.vstack((FLU_TO_FRD @ allocation[:3], FLU_TO_FRD @ allocation[3:]))
    signs = np.zeros_like(frd)
    for part in (slice(0, 3), slice(3, 6)):  # a term under a fifth of the largest is none
        block = frd[part]
        signs[part] = np.where(np.abs(block) > 0.2 * np.abs(block).max(), np.sign(block), 0.0)
    taken: list[tuple[int, float]] = []
    for motor, (roll, pitch, yaw, throttle, forward, lateral) in enumerate(VECTORED_6DOF, start=1):
        # a motor's positive output: its factors as a wrench, forward-right-down (throttle up)
        wanted = np.array([forward, lateral, -throttle, roll, pitch, yaw], dtype=float)
        matches = [
            (j, s) for j in range(frd.shape[1]) for s in (1.0, -1.0)
            if np.array_equal(s * signs[:, j], wanted) and j not in [t for t, _ in taken]
        ]  # fmt: skip
        if len(matches) != 1:
            raise ConfigError(
                "simulation.robot",
                f"{robot.name}: ArduSub's vectored 6-DoF motor {motor} (factors {VECTORED_6DOF[motor - 1]}) "
                f"is {len(matches)} of its thrusters, not one",
            )
        taken.append(matches[0])
    return taken


def thrusts_n(
    pwm_us: tuple[int, ...],
    mapping: list[tuple[int, float]],
    forward_max_n: float,
    reverse_max_n: float,
    count: int,
) -> np.ndarray:
    """The thrusters' commanded thrusts [N] for the motors' PWM; a channel without a pulse (0, or
    outside 1000-2000 us) is neutral."""
    thrust = np.zeros(count)
    for motor, (j, sign) in enumerate(mapping):
        pwm = float(pwm_us[motor]) if motor < len(pwm_us) else 0.0
        fraction = (pwm - PWM_NEUTRAL_US) / PWM_SPAN_US if 1000.0 <= pwm <= 2000.0 else 0.0
        output = min(max(fraction, -1.0), 1.0)
        thrust[j] = sign * output * (forward_max_n if sign * output >= 0 else reverse_max_n)
    return thrust


def state_line(
    time_s: float,
    position_m_world: np.ndarray,
    quat_wxyz_world: np.ndarray,
    velocity_mps_world: np.ndarray,
    angular_velocity_radps_body: np.ndarray,
    acceleration_mps2_world: np.ndarray,
    g: Geodesy,
) -> bytes:
    """The JSON line ArduPilot reads (its parser wants `[a, b, c]` with a comma and a space)."""
    rotation = rotation_of(quat_wxyz_world)  # body forward-left-up to the world (z up)
    world_to_ned = np.column_stack([g.ned_of(e) - g.ned_of(np.zeros(3)) for e in np.eye(3)])
    attitude = world_to_ned @ rotation @ FLU_TO_FRD  # body forward-right-down to north-east-down
    specific_force = rotation.T @ (acceleration_mps2_world + np.array([0.0, 0.0, GRAVITY_MPS2]))
    state = {
        "timestamp": time_s,
        "imu": {
            "gyro": list(FLU_TO_FRD @ angular_velocity_radps_body),
            "accel_body": list(FLU_TO_FRD @ specific_force),
        },
        "position": list(g.ned_of(position_m_world)),
        "velocity": list(world_to_ned @ velocity_mps_world),
        "quaternion": list(quat_wxyz_of(attitude)),
    }
    return ("\n" + json.dumps(state, default=float) + "\n").encode()


class FrameCounter:
    """ArduPilot's frame count against the frames stepped (see the module's text)."""

    def __init__(self) -> None:
        self.last: int | None = None
        self.lost = 0
        self.resent = 0
        self.restarts = 0

    def take(self, count: int) -> str:
        """ "step", "again" (a resend: answer, do not step) or "restart" (then step)."""
        last, self.last = self.last, count
        if last is None:
            return "step"
        if count == last:
            self.resent += 1
            return "again"
        if count < last:
            self.restarts += 1
            return "restart"
        self.lost += count - last - 1
        return "step"
