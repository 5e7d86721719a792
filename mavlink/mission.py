"""MAVLink's mission protocol, as ArduPilot keeps a mission: uploaded item by item on the vehicle's
request (MISSION_COUNT, MISSION_REQUEST_INT, MISSION_ITEM_INT, MISSION_ACK), read back, cleared,
its current item set. Item 0 is home, as ArduPilot's; the waypoints (MAV_CMD_NAV_WAYPOINT) after it
are what abyss flies, in the world frame, in a global frame (altitude above mean sea level, or
relative to the surface: home) or the site's north-east-down."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from abyss.mavlink.geodesy import Geodesy

REQUEST_AGAIN_S = 1.0  # an item asked for and not come: asked again, as ArduPilot does
GIVE_UP_S = 10.0  # an upload no item of which came for this long is dropped
MAX_ITEMS = 1000  # onboard's waypoint lists' limit
GLOBAL_FRAMES = (mavlink.MAV_FRAME_GLOBAL, mavlink.MAV_FRAME_GLOBAL_INT)
RELATIVE_FRAMES = (mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT)
FRAMES = (*GLOBAL_FRAMES, *RELATIVE_FRAMES, mavlink.MAV_FRAME_LOCAL_NED)

Say = list[mavlink.MAVLink_message]


@dataclass(frozen=True)
class Item:
    seq: int
    frame: int
    command: int
    params: tuple[float, float, float, float]
    x: int  # degE7 in a global frame; [m] * 1e4 in MAV_FRAME_LOCAL_NED (MISSION_ITEM_INT's scaling)
    y: int
    z: float

    @staticmethod
    def of(msg: mavlink.MAVLink_message) -> Item:
        """From a MISSION_ITEM_INT, or the float MISSION_ITEM (its x, y scaled as the _INT's)."""
        x, y = msg.x, msg.y
        if msg.get_type() == "MISSION_ITEM":
            scale = 1e7 if msg.frame in GLOBAL_FRAMES + RELATIVE_FRAMES else 1e4
            x, y = round(x * scale), round(y * scale)
        return Item(
            msg.seq, msg.frame, msg.command, (msg.param1, msg.param2, msg.param3, msg.param4), x, y, msg.z
        )

    def message(self, target: tuple[int, int], current: int) -> mavlink.MAVLink_message:
        return mavlink.MAVLink_mission_item_int_message(
            *target, self.seq, self.frame, self.command, int(self.seq == current), 1, *self.params,
            self.x, self.y, self.z, mavlink.MAV_MISSION_TYPE_MISSION,
        )  # fmt: skip

    def position_m_world(self, g: Geodesy) -> np.ndarray:
        if self.frame == mavlink.MAV_FRAME_LOCAL_NED:
            return g.world_of(np.array([self.x / 1e4, self.y / 1e4, self.z]))
        altitude = self.z + (g.datum.surface_amsl_m if self.frame in RELATIVE_FRAMES else 0.0)
        return g.world_of_geodetic(self.x / 1e7, self.y / 1e7, altitude)


class Mission:
    def __init__(self) -> None:
        self.items: list[Item] = []
        self.current = 1  # the item in hand (0 is home)
        self.version = 0  # counts the missions taken: a new one replaces the one flown
        self._upload: list[Item | None] | None = None
        self._peer = (0, 0)  # who uploads
        self._asked_s = self._heard_s = 0.0

    def waypoints(self, g: Geodesy, yaw_rad: float) -> tuple[list[int], np.ndarray]:
        """The items flown from the current one (their seqs) and their rows of x, y, z [m, world],
        yaw [rad]: a waypoint's yaw (param4, degrees from north) where it gives one, else the one
        before's (the first: `yaw_rad`, where the vehicle points)."""
        seqs, rows = [], []
        for item in self.items[max(self.current, 1) :]:
            if item.command != mavlink.MAV_CMD_NAV_WAYPOINT:
                continue
            heading = item.params[3]
            if math.isfinite(heading):
                yaw_rad = g.yaw_rad(math.radians(heading))
            seqs.append(item.seq)
            rows.append([*item.position_m_world(g), yaw_rad])
        return seqs, np.array(rows).reshape(-1, 4)

    def handle(self, msg: mavlink.MAVLink_message, now_s: float) -> tuple[Say, str]:
        """The answer to a mission message, and a text to say ("" none)."""
        kind = msg.get_type()
        if getattr(msg, "mission_type", 0) != mavlink.MAV_MISSION_TYPE_MISSION:  # fences, rally points
            return [self._ack(msg, mavlink.MAV_MISSION_UNSUPPORTED)], ""
        if kind == "MISSION_COUNT":
            if not 0 < msg.count <= MAX_ITEMS + 1:
                return [
                    self._ack(msg, mavlink.MAV_MISSION_NO_SPACE)
                ], f"Mission: {msg.count} items, at most {MAX_ITEMS + 1}"
            self._upload, self._peer = [None] * msg.count, (msg.get_srcSystem(), msg.get_srcComponent())
            self._heard_s = now_s
            return [self._request(0, now_s)], ""
        if kind in ("MISSION_ITEM_INT", "MISSION_ITEM"):
            return self._item(Item.of(msg), now_s)
        if kind == "MISSION_REQUEST_LIST":
            return [mavlink.MAVLink_mission_count_message(*_peer(msg), len(self.items), 0)], ""
        if kind in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
            if 0 <= msg.seq < len(self.items):
                return [self.items[msg.seq].message(_peer(msg), self.current)], ""
            return [self._ack(msg, mavlink.MAV_MISSION_INVALID_SEQUENCE)], ""
        if kind == "MISSION_CLEAR_ALL":
            self.items, self.current = [], 1
            self.version += 1
            return [self._ack(msg, mavlink.MAV_MISSION_ACCEPTED)], ""
        if kind == "MISSION_SET_CURRENT":
            if 0 < msg.seq < len(self.items):
                self.current = msg.seq
                self.version += 1
            return [], ""
        return [], ""

    def _item(self, item: Item, now_s: float) -> tuple[Say, str]:
        upload = self._upload
        if upload is None or not 0 <= item.seq < len(upload):
            return [], ""
        if item.frame not in FRAMES and item.command == mavlink.MAV_CMD_NAV_WAYPOINT:
            self._upload = None
            return [
                self._ack_to(mavlink.MAV_MISSION_UNSUPPORTED_FRAME)
            ], f"Mission: item {item.seq}'s frame {item.frame} not flown"
        upload[item.seq] = item
        self._heard_s = now_s
        missing = next((i for i, got in enumerate(upload) if got is None), None)
        if missing is not None:
            return [self._request(missing, now_s)], ""
        self.items = [i for i in upload if i is not None]
        self.current, self._upload = 1, None
        self.version += 1
        return [self._ack_to(mavlink.MAV_MISSION_ACCEPTED)], ""

    def tick(self, now_s: float) -> Say:
        """An upload's item asked for again when it has not come, or the upload dropped."""
        if self._upload is None:
            return []
        if now_s - self._heard_s > GIVE_UP_S:
            self._upload = None
            return [self._ack_to(mavlink.MAV_MISSION_OPERATION_CANCELLED)]
        if now_s - self._asked_s < REQUEST_AGAIN_S:
            return []
        missing = next(i for i, got in enumerate(self._upload) if got is None)
        return [self._request(missing, now_s)]

    def _request(self, seq: int, now_s: float) -> mavlink.MAVLink_message:
        self._asked_s = now_s
        return mavlink.MAVLink_mission_request_int_message(*self._peer, seq, mavlink.MAV_MISSION_TYPE_MISSION)

    def _ack_to(self, result: int) -> mavlink.MAVLink_message:
        return mavlink.MAVLink_mission_ack_message(*self._peer, result, mavlink.MAV_MISSION_TYPE_MISSION)

    def _ack(self, msg: mavlink.MAVLink_message, result: int) -> mavlink.MAVLink_message:
        return mavlink.MAVLink_mission_ack_message(*_peer(msg), result, getattr(msg, "mission_type", 0))


def _peer(msg: mavlink.MAVLink_message) -> tuple[int, int]:
    return msg.get_srcSystem(), msg.get_srcComponent()
