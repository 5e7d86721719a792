"""What the vehicle tells its ground stations unasked, as ArduSub's streams do: each message built
from onboard's own state (its navigation estimate, as ArduSub reports its EKF's, and its
controllers' telemetry) in MAVLink's frames (north-east-down, forward-right-down, degE7, cdeg), and
the rates it goes at on a link; a high-latency link gets HIGH_LATENCY2 alone, every 5 s."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from abyss.common.geometry import roll_pitch_of, rotation_of, yaw_of
from abyss.interface.messages import NavState, Telemetry
from abyss.mavlink.ardusub import SubMode, base_mode
from abyss.mavlink.geodesy import Geodesy

SURFACE_PRESSURE_HPA = 1013.25
WATER_HPA_PER_M = 1025.0 * 9.80665 / 100.0  # sea water's column [hPa/m]
HIGH_LATENCY_PERIOD_S = 5.0  # ArduPilot's HIGH_LATENCY2 on a high-latency link
SENSORS = (  # SYS_STATUS: the IMU, the compass and the depth sensor, present, enabled and healthy
    mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO
    | mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG
    | mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
)
UNKNOWN_U16 = 65535  # MAVLink's "unknown" in a uint16 field (abyss has no battery model)

# the streams a full link gets, and their rates [Hz] (ArduSub's SRx_ groups, at BlueOS's rates);
# onboard's telemetry comes at 10 Hz, the fastest any of them can be
RATES_HZ: dict[str, float] = {
    "HEARTBEAT": 1.0,
    "SYS_STATUS": 1.0,
    "ATTITUDE": 10.0,
    "GLOBAL_POSITION_INT": 5.0,
    "LOCAL_POSITION_NED": 5.0,
    "VFR_HUD": 4.0,
    "SCALED_PRESSURE": 1.0,
    "SCALED_PRESSURE2": 2.0,
    "MISSION_CURRENT": 1.0,
}


@dataclass(frozen=True)
class Report:
    """What the vehicle knows at a moment, for its messages."""

    time_boot_ms: int
    mode: SubMode
    armed: bool
    system_status: int  # MAV_STATE
    estimate: NavState | None  # onboard's navigation estimate, once it has one
    telemetry: Telemetry | None
    mission_seq: int  # the mission item in hand
    mission_total: int
    target_m_world: np.ndarray | None  # where the vehicle is flying to


def heartbeat(r: Report) -> mavlink.MAVLink_message:
    return mavlink.MAVLink_heartbeat_message(
        mavlink.MAV_TYPE_SUBMARINE,
        mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
        base_mode(r.mode, r.armed),
        int(r.mode),
        r.system_status,
        3,
    )


def sys_status(r: Report) -> mavlink.MAVLink_message:
    return mavlink.MAVLink_sys_status_message(
        SENSORS, SENSORS, SENSORS, 0, UNKNOWN_U16, -1, -1, 0, 0, 0, 0, 0, 0
    )


def _attitude_frd(estimate: NavState) -> tuple[float, float, float]:
    """Roll, pitch [rad, forward-right-down] and yaw [rad, from north] of the estimate (forward-
    left-up in a z-up world): roll as it is, pitch and the world's yaw the other way."""
    roll, pitch = roll_pitch_of(estimate.orientation_wxyz_world)
    return roll, -pitch, yaw_of(estimate.orientation_wxyz_world)


def attitude(r: Report, g: Geodesy) -> mavlink.MAVLink_message | None:
    if r.estimate is None:
        return None
    roll, pitch, yaw = _attitude_frd(r.estimate)
    p, q, rate = (float(v) for v in r.estimate.angular_velocity_radps_body)
    return mavlink.MAVLink_attitude_message(
        r.time_boot_ms, roll, pitch, math.remainder(g.heading_rad(yaw), 2.0 * math.pi), p, -q, -rate
    )


def velocity_ned(estimate: NavState, g: Geodesy) -> np.ndarray:
    """The velocity [m/s] north, east, down."""
    world = rotation_of(estimate.orientation_wxyz_world) @ estimate.velocity_mps_body
    return g.ned_of(world) - g.ned_of(np.zeros(3))


def local_position_ned(r: Report, g: Geodesy) -> mavlink.MAVLink_message | None:
    if r.estimate is None:
        return None
    north, east, down = g.ned_of(r.estimate.position_m_world)
    vn, ve, vd = velocity_ned(r.estimate, g)
    return mavlink.MAVLink_local_position_ned_message(r.time_boot_ms, north, east, down, vn, ve, vd)


def global_position_int(r: Report, g: Geodesy) -> mavlink.MAVLink_message | None:
    if r.estimate is None:
        return None
    lat, lon, alt = g.geodetic_of(r.estimate.position_m_world)
    vn, ve, vd = velocity_ned(r.estimate, g)
    heading = math.degrees(g.heading_rad(yaw_of(r.estimate.orientation_wxyz_world)))
    return mavlink.MAVLink_global_position_int_message(
        r.time_boot_ms,
        round(lat * 1e7),
        round(lon * 1e7),
        round(alt * 1000.0),
        round(float(r.estimate.position_m_world[2]) * 1000.0),  # relative to the surface (home)
        round(vn * 100.0),
        round(ve * 100.0),
        round(vd * 100.0),
        round(heading * 100.0) % 36000,
    )


def vfr_hud(r: Report, g: Geodesy) -> mavlink.MAVLink_message | None:
    if r.estimate is None:
        return None
    vn, ve, vd = velocity_ned(r.estimate, g)
    speed = math.hypot(vn, ve)
    heading = round(math.degrees(g.heading_rad(yaw_of(r.estimate.orientation_wxyz_world)))) % 360
    effort = 0 if r.telemetry is None else round(100.0 * abs(float(r.telemetry.effort_body[2])))
    alt = g.geodetic_of(r.estimate.position_m_world)[2]
    return mavlink.MAVLink_vfr_hud_message(speed, speed, heading, effort, alt, -vd)


def scaled_pressure(r: Report) -> mavlink.MAVLink_message:
    """The enclosure's barometer: the air inside, at the surface's pressure."""
    return mavlink.MAVLink_scaled_pressure_message(r.time_boot_ms, SURFACE_PRESSURE_HPA, 0.0, 0)


def scaled_pressure2(r: Report) -> mavlink.MAVLink_message | None:
    """The depth sensor (a Bar30 on a BlueROV2: ArduSub's second barometer), from the depth."""
    if r.estimate is None:
        return None
    depth_m = max(0.0, -float(r.estimate.position_m_world[2]))
    return mavlink.MAVLink_scaled_pressure2_message(
        r.time_boot_ms, SURFACE_PRESSURE_HPA + WATER_HPA_PER_M * depth_m, 0.0, 0
    )


def mission_current(r: Report) -> mavlink.MAVLink_message:
    return mavlink.MAVLink_mission_current_message(r.mission_seq, r.mission_total)


def high_latency2(r: Report, g: Geodesy) -> mavlink.MAVLink_message:
    """ArduPilot's HIGH_LATENCY2: the state in one message (base_mode in custom0, as ArduPilot)."""
    lat = lon = alt = heading = climb = speed = 0.0
    if r.estimate is not None:
        lat, lon, alt = g.geodetic_of(r.estimate.position_m_world)
        heading = math.degrees(g.heading_rad(yaw_of(r.estimate.orientation_wxyz_world)))
        vn, ve, vd = velocity_ned(r.estimate, g)
        climb, speed = -vd, math.hypot(vn, ve)
    target_alt, distance = alt, 0.0
    if r.target_m_world is not None and r.estimate is not None:
        target_alt = g.geodetic_of(r.target_m_world)[2]
        distance = float(np.linalg.norm(r.target_m_world - r.estimate.position_m_world))
    return mavlink.MAVLink_high_latency2_message(
        r.time_boot_ms,
        mavlink.MAV_TYPE_SUBMARINE,
        mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
        int(r.mode),
        round(lat * 1e7),
        round(lon * 1e7),
        round(alt),
        round(target_alt),
        round(heading / 2.0) % 180,
        round(heading / 2.0) % 180,
        min(round(distance / 10.0), 65535),
        0,
        0,
        0,
        min(round(speed * 5.0), 255),
        0,
        0,
        255,
        255,
        0,
        max(-128, min(127, round(climb * 10.0))),
        -1,
        r.mission_seq,
        0,
        int.from_bytes(bytes([base_mode(r.mode, r.armed)]), signed=True),  # an int8 field: the bits kept
        0,
        0,
    )


# each stream's message from the report and the site's frame, built by name (RATES_HZ's and HIGH_LATENCY2)
BUILDERS: dict[str, Callable[[Report, Geodesy], mavlink.MAVLink_message | None]] = {
    "HEARTBEAT": lambda r, g: heartbeat(r),
    "SYS_STATUS": lambda r, g: sys_status(r),
    "ATTITUDE": attitude,
    "GLOBAL_POSITION_INT": global_position_int,
    "LOCAL_POSITION_NED": local_position_ned,
    "VFR_HUD": vfr_hud,
    "SCALED_PRESSURE": lambda r, g: scaled_pressure(r),
    "SCALED_PRESSURE2": lambda r, g: scaled_pressure2(r),
    "MISSION_CURRENT": lambda r, g: mission_current(r),
    "HIGH_LATENCY2": high_latency2,
}


def stream(name: str, r: Report, g: Geodesy) -> mavlink.MAVLink_message | None:
    """The message `name` of RATES_HZ now; None where there is nothing to say yet."""
    return BUILDERS[name](r, g)
