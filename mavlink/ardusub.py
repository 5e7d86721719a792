"""ArduSub's numbers, as its ground stations know them (ArduSub/mode.h, Parameters.cpp, config.h;
the figures carry over, the code does not): its custom modes, the mode flags its heartbeat sets,
and the parameters abyss's vehicle keeps, with ArduSub's defaults and ranges."""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

from pymavlink.dialects.v20 import ardupilotmega as mavlink


class SubMode(IntEnum):
    """ArduSub's custom modes (HEARTBEAT.custom_mode); abyss flies the ones in FLOWN."""

    STABILIZE = 0
    ACRO = 1
    ALT_HOLD = 2  # "depth hold"
    AUTO = 3
    GUIDED = 4
    CIRCLE = 7
    SURFACE = 9
    POSHOLD = 16
    MANUAL = 19
    MOTOR_DETECT = 20
    SURFTRAK = 21


FLOWN = (SubMode.MANUAL, SubMode.STABILIZE, SubMode.ALT_HOLD, SubMode.POSHOLD, SubMode.GUIDED, SubMode.AUTO)
BOOT_MODE = SubMode.MANUAL  # as BlueOS's ArduSub comes up
PILOT_MODES = (SubMode.MANUAL, SubMode.STABILIZE, SubMode.ALT_HOLD, SubMode.POSHOLD)  # the sticks fly


def base_mode(mode: SubMode, armed: bool) -> int:
    """HEARTBEAT.base_mode as ArduSub sets it: manual input and custom modes always, stabilised but
    in manual and acro, guided in the modes that fly to positions, armed."""
    flags = mavlink.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED | mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    if mode not in (SubMode.MANUAL, SubMode.ACRO):
        flags |= mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
    if mode in (SubMode.AUTO, SubMode.GUIDED, SubMode.CIRCLE, SubMode.POSHOLD):
        flags |= mavlink.MAV_MODE_FLAG_GUIDED_ENABLED
    if armed:
        flags |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    return flags


# the GCS failsafe's actions (FS_GCS_ENABLE) and the pilot input's (FS_PILOT_INPUT)
FS_GCS_WARN, FS_GCS_DISARM, FS_GCS_HOLD, FS_GCS_SURFACE = 1, 2, 3, 4
FS_PILOT_WARN, FS_PILOT_DISARM = 1, 2
FRAME_VECTORED_6DOF, FRAME_CUSTOM = 2, 7  # FRAME_CONFIG: the BlueROV2 Heavy's; any other layout


@dataclass(frozen=True)
class Param:
    """One parameter: its default (ArduSub's), range, MAVLink type, and what it does here."""

    name: str
    default: float
    lo: float
    hi: float
    type: int  # MAV_PARAM_TYPE
    doc: str
    reboot: bool = False  # taken, but in effect only from the next start (ArduSub's @RebootRequired)


PARAMS: tuple[Param, ...] = (
    Param("SYSID_THISMAV", 1, 1, 255, mavlink.MAV_PARAM_TYPE_INT16, "the vehicle's system id", reboot=True),
    Param(
        "SYSID_MYGCS",
        255,
        1,
        255,
        mavlink.MAV_PARAM_TYPE_INT16,
        "the ground station the GCS failsafe watches",
    ),
    Param(
        "FS_GCS_ENABLE",
        FS_GCS_DISARM,
        0,
        4,
        mavlink.MAV_PARAM_TYPE_INT8,
        "GCS heartbeat lost: 0 nothing, 1 warn, 2 disarm, 3 depth hold, 4 surface",
    ),
    Param("FS_GCS_TIMEOUT", 5.0, 0.1, 120.0, mavlink.MAV_PARAM_TYPE_REAL32, "GCS heartbeat lost after [s]"),
    Param(
        "FS_PILOT_INPUT",
        FS_PILOT_DISARM,
        0,
        2,
        mavlink.MAV_PARAM_TYPE_INT8,
        "MANUAL_CONTROL lost: 0 nothing, 1 warn (neutral sticks), 2 disarm",
    ),
    Param("FS_PILOT_TIMEOUT", 3.0, 0.1, 3.0, mavlink.MAV_PARAM_TYPE_REAL32, "MANUAL_CONTROL lost after [s]"),
    Param(
        "THR_DZ",
        100,
        0,
        300,
        mavlink.MAV_PARAM_TYPE_INT16,
        "the throttle's dead zone about 500 in depth and position hold",
    ),
    Param(
        "JS_GAIN_DEFAULT",
        0.5,
        0.1,
        1.0,
        mavlink.MAV_PARAM_TYPE_REAL32,
        "the sticks' gain on onboard's speed limits",
    ),
    Param(
        "SURFACE_DEPTH",
        -10.0,
        -100.0,
        0.0,
        mavlink.MAV_PARAM_TYPE_REAL32,
        "the depth read at the surface [cm]",
    ),
    Param(
        "FRAME_CONFIG",
        FRAME_VECTORED_6DOF,
        0,
        7,
        mavlink.MAV_PARAM_TYPE_INT8,
        "the thrusters' layout: 2 vectored 6-DoF (the BlueROV2 Heavy), 7 custom",
        reboot=True,
    ),
)
