"""Onboard as the companion computer of a team's ArduSub (mavlink.autopilot), as BlueOS is one: it
routes MAVLink between ArduSub and the ground stations on both links (whole frames, both ways, as
mavlink-router does), and hands onboard's own goals to ArduSub: the waypoint onboard flies towards
becomes ArduSub's guided target (armed, GUIDED, SET_POSITION_TARGET_LOCAL_NED in the site's
north-east-down, which is ArduSub's local frame when it runs with the site's datum as its home:
`abyss sitl` prints the --home to give it). Onboard's own velocity commands go nowhere then: the
simulation's physics is ArduSub's to drive; the arm stays onboard's."""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from abyss.config import Config, site_of
from abyss.mavlink.ardusub import SubMode
from abyss.mavlink.geodesy import Geodesy

COMPONENT = mavlink.MAV_COMP_ID_ONBOARD_COMPUTER
RESEND_S = 1.0  # the target, the mode and the arming, again until ArduSub's heartbeat shows them
# SET_POSITION_TARGET_LOCAL_NED's type_mask: the position and the yaw, nothing else
POSITION_AND_YAW = 0b0000_1001_1111_1000
log = logging.getLogger(__name__)


@dataclass
class Goal:
    """What onboard wants of the vehicle now: to fly (its operator says auto) towards a waypoint."""

    fly: bool
    waypoint: np.ndarray | None  # x, y, z [m, world], yaw [rad]


class Companion:
    def __init__(self, config: Config) -> None:
        scheme, _, address = config.mavlink.autopilot.partition(":")
        device = f"tcp:{address}" if scheme == "tcp" else f"udpout:{address}"
        self.link: Any = mavutil.mavlink_connection(
            device,
            source_system=config.mavlink.system_id,
            source_component=COMPONENT,
            dialect="ardupilotmega",
        )
        self.geodesy = Geodesy(site_of(config).spec.datum)
        self.target_system = config.mavlink.system_id
        self.heartbeat: Any = None  # ArduSub's latest
        self.sent_s = -math.inf
        self.sent: np.ndarray | None = None
        self.routed = {"in": 0, "out": 0}

    def to_autopilot(self, data: bytes) -> None:
        """A ground station's frames, on to ArduSub."""
        self.link.write(data)
        self.routed["in"] += 1

    def from_autopilot(self, max_bytes: int) -> list[bytes]:
        """ArduSub's frames since the last call, whole, in runs of at most `max_bytes` (one
        message each, for every ground link)."""
        runs, run = [], bytearray()
        while (msg := self.link.recv_msg()) is not None:
            if msg.get_type() == "BAD_DATA":
                continue
            if msg.get_type() == "HEARTBEAT" and msg.get_srcComponent() == mavlink.MAV_COMP_ID_AUTOPILOT1:
                self.heartbeat = msg
            frame = msg.get_msgbuf()
            if len(run) + len(frame) > max_bytes:
                runs.append(bytes(run))
                run = bytearray()
            run += frame
        if run:
            runs.append(bytes(run))
        self.routed["out"] += len(runs)
        return runs

    def hand(self, goal: Goal, now_s: float) -> None:
        """Onboard's goal to ArduSub: armed, in GUIDED, flying to the waypoint; sent when it changes
        and again each RESEND_S until ArduSub's heartbeat shows it armed in GUIDED."""
        if not goal.fly or goal.waypoint is None:
            return
        beat = self.heartbeat
        armed = beat is not None and beat.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        guided = beat is not None and beat.custom_mode == SubMode.GUIDED
        changed = self.sent is None or not np.allclose(self.sent, goal.waypoint, atol=1e-3)
        if not changed and armed and guided:
            return
        if not changed and now_s - self.sent_s < RESEND_S:
            return
        mav = self.link.mav
        if not guided:
            mav.set_mode_send(self.target_system, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, SubMode.GUIDED)
        if not armed:
            mav.command_long_send(
                self.target_system, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0
            )
        north, east, down = self.geodesy.ned_of(goal.waypoint[:3])
        heading = math.remainder(self.geodesy.heading_rad(float(goal.waypoint[3])), 2.0 * math.pi)
        mav.set_position_target_local_ned_send(
            0, self.target_system, 1, mavlink.MAV_FRAME_LOCAL_NED, POSITION_AND_YAW,
            north, east, down, 0, 0, 0, 0, 0, 0, heading, 0,
        )  # fmt: skip
        self.sent, self.sent_s = goal.waypoint.copy(), now_s

    def close(self) -> None:
        self.link.close()
