"""Onboard's MAVLink side: the vehicle as ArduSub presents itself to its ground stations (system 1,
component 1, MAVLink 2), mapped onto onboard's own goals, so that a dive flown from a ground station
is flown and judged as any other. Without Zenoh: frames in, frames and onboard's commands out.

- Armed or not: disarmed, onboard holds station (abyss has no thrusters-off: the vehicle keeps
  where it is rather than drifting); armed, it flies the mode's goal.
- Manual, stabilize, depth hold, position hold: MANUAL_CONTROL's sticks (x forward, y right, z
  throttle with 500 neutral, r yaw right; scaled by JS_GAIN_DEFAULT on onboard's speed limits) set
  a goal ahead of the vehicle that onboard's waypoint law flies at the sticks' speed; an axis whose
  stick is centred (within THR_DZ for the throttle in depth and position hold) holds where it was
  when it centred. So the four differ less than ArduSub's (whose manual is thrust, not velocity).
- Guided: SET_POSITION_TARGET_LOCAL_NED / _GLOBAL_INT positions; auto: the mission's waypoints.
- The GCS failsafe (FS_GCS_ENABLE, FS_GCS_TIMEOUT: SYSID_MYGCS's heartbeat, once seen, silent) and
  the pilot input failsafe (FS_PILOT_INPUT, FS_PILOT_TIMEOUT: MANUAL_CONTROL silent) as ArduSub
  runs them: act once, said by STATUSTEXT, the heartbeat's system status critical while on.
- On a high-latency link (the satellite's side, ardusub.HIGH_LATENCY) HIGH_LATENCY2 every 5 s in
  place of the heartbeat and the streams; every link gets its answers."""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from abyss.common.geometry import rotation_of_rpy, yaw_of
from abyss.config import Config, robot_of, site_of
from abyss.interface.messages import (
    GROUND_LINKS,
    CommandAck,
    NavState,
    OperatorMode,
    Telemetry,
    Waypoints,
    new_id,
)
from abyss.mavlink import ardusub, streams
from abyss.mavlink.ardusub import FLOWN, PILOT_MODES, SubMode
from abyss.mavlink.geodesy import Geodesy
from abyss.mavlink.mission import Mission
from abyss.mavlink.params import Params

WARN_EVERY_S = 30.0  # the GCS failsafe's warning, again while it lasts (ArduSub's)
VERSION = (0, 1, 0)  # AUTOPILOT_VERSION's flight software: abyss's, not ArduSub's
CAPABILITIES = (
    mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
    | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
)
IGNORE_POSITION = 0b111  # SET_POSITION_TARGET_*'s type_mask: the position not given
IGNORE_YAW = 0x400
Command = Waypoints | OperatorMode


@dataclass
class VehicleOutputs:
    frames: dict[str, bytearray] = field(default_factory=lambda: {link: bytearray() for link in GROUND_LINKS})
    commands: list[Command] = field(default_factory=list)  # for onboard's core, as the operator's


class MavlinkVehicle:
    def __init__(self, config: Config, now_s: float) -> None:
        m = config.mavlink
        self.onboard = config.onboard
        self.geodesy = Geodesy(site_of(config).spec.datum)
        # eight thrusters: ArduSub's vectored 6-DoF frame, the BlueROV2 Heavy's; any other layout custom
        eight = len(robot_of(config).marine.thrusters.names) == 8
        frame = ardusub.FRAME_VECTORED_6DOF if eight else ardusub.FRAME_CUSTOM
        self.params = Params(
            {"SYSID_THISMAV": m.system_id, "SYSID_MYGCS": m.gcs_system_id, "FRAME_CONFIG": frame}
        )
        self.system_id = m.system_id
        self.encoders = {link: mavlink.MAVLink(None, m.system_id, 1) for link in GROUND_LINKS}
        self.decoders = {link: mavlink.MAVLink(None) for link in GROUND_LINKS}
        for decoder in self.decoders.values():
            decoder.robust_parsing = True
        self.high_latency = {"tether": False, "satellite": m.satellite_high_latency}
        self.next_s = {
            link: dict.fromkeys((*streams.RATES_HZ, "HIGH_LATENCY2"), now_s) for link in GROUND_LINKS
        }
        self.boot_s = now_s
        self.mode, self.armed = ardusub.BOOT_MODE, False
        self.mission = Mission()
        self.upload_link = "tether"  # where the mission in upload comes from
        self.flown_mission = -1  # the mission version flown in auto
        self.mission_seqs: list[int] = []
        self.gcs_seen_s: float | None = None
        self.gcs_failsafe, self.gcs_warned_s = False, -math.inf
        self.pilot_s, self.pilot_failsafe = now_s, False
        self.sticks = np.zeros(4)  # forward, right, up, yaw right, each in [-1, 1]
        self.held: dict[str, float | np.ndarray] = {}  # what a centred axis holds: "xy", "z", "yaw"
        self.guided: np.ndarray | None = None  # x, y, z [m, world], yaw [rad]
        self.goal: np.ndarray | None = None  # the last waypoint sent
        self.goal_id = -1  # ... its command's id
        self.ours: dict[int, str] = {}  # the commands this side sent onboard: what each was for
        self.pilot_goals: deque[int] = deque(maxlen=8)  # the latest waypoints that are a pilot's goal
        self.operator_mode = ""
        self.reached = 0  # of the mission's waypoints, reported reached
        self.estimate: NavState | None = None
        self.telemetry: Telemetry | None = None
        self.broadcast: list[mavlink.MAVLink_message] = []  # to every link: texts, items reached
        self.malformed = 0

    # -- what came in ----------------------------------------------------------------------
    def receive(self, link: str, data: bytes, now_s: float, out: VehicleOutputs) -> list[str]:
        """Take a ground station's frames on `link`; the reasons of the malformed ones (dropped)."""
        bad = []
        for msg in self.decoders[link].parse_buffer(data) or []:
            if msg.get_type() == "BAD_DATA":
                bad.append(f"MAVLink: {msg.reason}")
                continue
            self._take(link, msg, now_s, out)
        self.malformed += len(bad)
        return bad

    def _take(self, link: str, msg: mavlink.MAVLink_message, now_s: float, out: VehicleOutputs) -> None:
        kind = msg.get_type()
        target = getattr(msg, "target_system", getattr(msg, "target", self.system_id))
        if target not in (0, self.system_id):
            return
        from_gcs = msg.get_srcSystem() == self.params["SYSID_MYGCS"]
        if kind == "HEARTBEAT":
            if from_gcs:
                self.gcs_seen_s = now_s
        elif kind == "MANUAL_CONTROL":
            if not from_gcs:  # ArduSub takes the sticks of its own ground station alone
                return
            self.gcs_seen_s = now_s  # and counts them as its heartbeat, as ArduSub does
            self.sticks = np.array([msg.x / 1000.0, msg.y / 1000.0, (msg.z - 500) / 500.0, msg.r / 1000.0])
            self.sticks = np.clip(self.sticks, -1.0, 1.0)
            self.pilot_s, self.pilot_failsafe = now_s, False
        elif kind == "SET_MODE":
            result = self._set_mode(msg.custom_mode)
            self._send(
                link, mavlink.MAVLink_command_ack_message(mavlink.MAVLINK_MSG_ID_SET_MODE, result), out
            )
        elif kind in ("COMMAND_LONG", "COMMAND_INT"):
            self._command(link, msg, out)
        elif kind in ("SET_POSITION_TARGET_LOCAL_NED", "SET_POSITION_TARGET_GLOBAL_INT"):
            self._target(msg)
        elif kind.startswith("PARAM_"):
            self._say_all(link, self.params.handle(msg), out)
        elif kind.startswith("MISSION_"):
            if kind == "MISSION_COUNT":
                self.upload_link = link
            self._say_all(link, self.mission.handle(msg, now_s), out)

    def _say_all(
        self, link: str, answer: tuple[list[mavlink.MAVLink_message], str], out: VehicleOutputs
    ) -> None:
        messages, text = answer
        for msg in messages:
            self._send(link, msg, out)
        if text:
            self.say(mavlink.MAV_SEVERITY_WARNING, text)

    def _command(self, link: str, msg: mavlink.MAVLink_message, out: VehicleOutputs) -> None:
        command, result = msg.command, mavlink.MAV_RESULT_ACCEPTED
        if command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
            self._arm(msg.param1 == 1.0)
        elif command == mavlink.MAV_CMD_DO_SET_MODE:
            result = self._set_mode(int(msg.param2))
        elif command == mavlink.MAV_CMD_MISSION_START:
            result = self._set_mode(SubMode.AUTO) if self.armed else mavlink.MAV_RESULT_DENIED
        elif command == mavlink.MAV_CMD_CONTROL_HIGH_LATENCY:
            self.high_latency[link] = msg.param1 == 1.0
        elif command in (mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, mavlink.MAV_CMD_REQUEST_MESSAGE):
            wanted = (
                mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION
                if command != mavlink.MAV_CMD_REQUEST_MESSAGE
                else msg.param1
            )
            if wanted == mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
                self._send(link, autopilot_version(), out)
            else:
                result = mavlink.MAV_RESULT_UNSUPPORTED
        else:
            result = mavlink.MAV_RESULT_UNSUPPORTED
        ack = mavlink.MAVLink_command_ack_message(
            command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()
        )
        self._send(link, ack, out)

    def _arm(self, arm: bool) -> None:
        if arm != self.armed:
            self.armed = arm
            self.held.clear()
            self.say(mavlink.MAV_SEVERITY_INFO, "Arming motors" if arm else "Disarming motors")

    def _set_mode(self, number: int) -> int:
        try:
            mode = SubMode(number)
        except ValueError:
            return mavlink.MAV_RESULT_DENIED
        if mode not in FLOWN:
            self.say(
                mavlink.MAV_SEVERITY_WARNING, f"Flight mode change failed: {mode.name} not flown by abyss"
            )
            return mavlink.MAV_RESULT_UNSUPPORTED
        if mode != self.mode:
            self.mode = mode
            self.held.clear()
            self.flown_mission, self.guided = -1, None
        return mavlink.MAV_RESULT_ACCEPTED

    def _target(self, msg: mavlink.MAVLink_message) -> None:
        if self.mode != SubMode.GUIDED or msg.type_mask & IGNORE_POSITION:
            self.say(mavlink.MAV_SEVERITY_WARNING, "Guided: position targets only, in guided mode")
            return
        if msg.get_type() == "SET_POSITION_TARGET_LOCAL_NED":
            if msg.coordinate_frame != mavlink.MAV_FRAME_LOCAL_NED:
                self.say(
                    mavlink.MAV_SEVERITY_WARNING,
                    f"Guided: frame {msg.coordinate_frame} not taken (LOCAL_NED)",
                )
                return
            position = self.geodesy.world_of(np.array([msg.x, msg.y, msg.z]))
        else:
            position = self.geodesy.world_of_geodetic(msg.lat_int / 1e7, msg.lon_int / 1e7, msg.alt)
        yaw = self._yaw_now() if msg.type_mask & IGNORE_YAW else self.geodesy.yaw_rad(msg.yaw)
        self.guided = np.r_[position, yaw]

    # -- onboard's answers -----------------------------------------------------------------
    def answered(self, acks: Iterable[CommandAck]) -> list[CommandAck]:
        """Take onboard's answers to this side's commands (a refusal said); the others returned."""
        others = []
        for ack in acks:
            what = self.ours.pop(ack.command_id, None)
            if what is None:
                others.append(ack)
            elif not ack.accepted:
                self.say(mavlink.MAV_SEVERITY_WARNING, f"{what} refused: {ack.reason}"[:50])
        return others

    # -- a control period ------------------------------------------------------------------
    def step(
        self, now_s: float, telemetry: Telemetry | None, estimates: list[NavState], out: VehicleOutputs
    ) -> None:
        """The failsafes, the goal for onboard, and what is due to each link (into `out`)."""
        if telemetry is not None:
            self.telemetry = telemetry
        if estimates:
            self.estimate = estimates[-1]
        self._failsafes(now_s)
        self._goals(out)
        self._progress()
        for msg in self.mission.tick(now_s):  # an upload's item asked again, on its uploader's link
            self._send(self.upload_link, msg, out)
        for link in GROUND_LINKS:
            self._streams(link, now_s, out)
            for msg in self.broadcast:
                self._send(link, msg, out)
        self.broadcast.clear()

    def say(self, severity: int, text: str) -> None:
        self.broadcast.append(mavlink.MAVLink_statustext_message(severity, text.encode()[:50]))

    def _progress(self) -> None:
        """The mission's waypoints onboard reached since the last period, told as ArduSub does."""
        t = self.telemetry
        if t is None or t.command_id != self.goal_id or not self.mission_seqs or self.mode != SubMode.AUTO:
            return
        for k in range(self.reached, min(t.waypoint_index, len(self.mission_seqs))):
            self.broadcast.append(mavlink.MAVLink_mission_item_reached_message(self.mission_seqs[k]))
            self.say(mavlink.MAV_SEVERITY_INFO, f"Reached command #{self.mission_seqs[k]}")
        self.reached = max(self.reached, t.waypoint_index)

    def _failsafes(self, now_s: float) -> None:
        p = self.params
        if self.gcs_seen_s is not None and p["FS_GCS_ENABLE"]:
            if now_s - self.gcs_seen_s < p["FS_GCS_TIMEOUT"]:
                self.gcs_failsafe = False
            else:
                if now_s - self.gcs_warned_s > WARN_EVERY_S:
                    self.gcs_warned_s = now_s
                    self.say(mavlink.MAV_SEVERITY_WARNING, f"MYGCS: {int(p['SYSID_MYGCS'])}, heartbeat lost")
                if not self.gcs_failsafe and self.armed:
                    self.gcs_failsafe = True
                    action = int(p["FS_GCS_ENABLE"])
                    if action == ardusub.FS_GCS_DISARM:
                        self._arm(False)
                    elif action in (ardusub.FS_GCS_HOLD, ardusub.FS_GCS_SURFACE):  # surface: not flown, held
                        self._set_mode(SubMode.ALT_HOLD)
        if p["FS_PILOT_INPUT"] and not self.pilot_failsafe and now_s - self.pilot_s > p["FS_PILOT_TIMEOUT"]:
            self.pilot_failsafe = True
            self.say(mavlink.MAV_SEVERITY_CRITICAL, "Lost manual control")
            self.sticks = np.zeros(4)
            if p["FS_PILOT_INPUT"] == ardusub.FS_PILOT_DISARM:
                self._arm(False)

    @property
    def system_status(self) -> int:
        if self.gcs_failsafe or (self.pilot_failsafe and self.armed):
            return mavlink.MAV_STATE_CRITICAL
        return mavlink.MAV_STATE_ACTIVE if self.armed else mavlink.MAV_STATE_STANDBY

    def _yaw_now(self) -> float:
        return yaw_of(self.estimate.orientation_wxyz_world) if self.estimate is not None else 0.0

    def _goals(self, out: VehicleOutputs) -> None:
        """The operator's mode and the waypoints for onboard from the mode's goal."""
        wanted = "auto" if self.armed else "hold"
        if wanted != self.operator_mode:
            self.operator_mode = wanted
            command = OperatorMode(new_id(), wanted)
            self.ours[command.command_id] = f"{wanted} mode"
            out.commands.append(command)
        if not self.armed or self.estimate is None:
            return
        if self.mode in PILOT_MODES:
            self._fly([self._pilot_goal()], "Pilot's goal", out, piloted=True)
        elif self.mode == SubMode.GUIDED and self.guided is not None:
            self._fly([self.guided], "Guided target", out, piloted=True)
        elif self.mode == SubMode.AUTO and self.flown_mission != self.mission.version:
            self.flown_mission = self.mission.version
            self.mission_seqs, rows = self.mission.waypoints(self.geodesy, self._yaw_now())
            self.reached = 0
            if len(rows):
                self._fly(list(rows), "Mission", out)
            else:
                self.say(mavlink.MAV_SEVERITY_WARNING, "Auto: no waypoints in the mission")

    def _fly(self, rows: list[np.ndarray], what: str, out: VehicleOutputs, piloted: bool = False) -> None:
        """Onboard's waypoints, sent when they change; `piloted`: a pilot's goal, not a mission."""
        goal = np.array(rows)
        if (
            self.goal is not None
            and goal.shape == self.goal.shape
            and np.allclose(goal, self.goal, atol=1e-3)
        ):
            return
        command = Waypoints(new_id(), goal)
        self.goal, self.goal_id = goal, command.command_id
        self.ours[command.command_id] = what
        if piloted:
            self.pilot_goals.append(command.command_id)
        out.commands.append(command)

    def _pilot_goal(self) -> np.ndarray:
        """The sticks' goal: x, y, z [m, world], yaw [rad] (see the module's text)."""
        assert self.estimate is not None
        position, yaw = self.estimate.position_m_world, self._yaw_now()
        gain, o = self.params["JS_GAIN_DEFAULT"], self.onboard
        forward, right, up, yaw_right = (float(v) for v in self.sticks)
        dead_band = self.params["THR_DZ"] / 500.0 if self.mode in (SubMode.ALT_HOLD, SubMode.POSHOLD) else 0.0
        if abs(up) <= dead_band:
            up = 0.0
        velocity = rotation_of_rpy(0.0, 0.0, yaw) @ np.array([forward, -right, up]) * gain * o.max_speed_mps
        ahead = position + velocity / o.kp_position
        goal = np.r_[ahead, yaw - yaw_right * gain * o.max_yaw_rate_radps / o.kp_heading]
        for axis, sticks, index in (
            ("xy", (forward, right), slice(0, 2)),
            ("z", (up,), slice(2, 3)),
            ("yaw", (yaw_right,), slice(3, 4)),
        ):
            if any(sticks):
                self.held.pop(axis, None)
            else:
                goal[index] = self.held.setdefault(axis, goal[index].copy())
        return goal

    # -- what goes out ---------------------------------------------------------------------
    def report(self, now_s: float) -> streams.Report:
        t = self.telemetry
        target = None if self.goal is None else self.goal[-1, :3]
        seq = self.mission_seqs[min(self.reached, len(self.mission_seqs) - 1)] if self.mission_seqs else 0
        return streams.Report(
            round((now_s - self.boot_s) * 1000.0) % 2**32, self.mode, self.armed, self.system_status,
            self.estimate, t, seq, len(self.mission.items), target,
        )  # fmt: skip

    def _streams(self, link: str, now_s: float, out: VehicleOutputs) -> None:
        due = self.next_s[link]
        names = ("HIGH_LATENCY2",) if self.high_latency[link] else tuple(streams.RATES_HZ)
        report = None
        for name in names:
            if now_s < due[name]:
                continue
            period = (
                streams.HIGH_LATENCY_PERIOD_S if name == "HIGH_LATENCY2" else 1.0 / streams.RATES_HZ[name]
            )
            due[name] = max(due[name] + period, now_s - period)
            report = report or self.report(now_s)
            msg = streams.stream(name, report, self.geodesy)
            if msg is not None:
                self._send(link, msg, out)

    def _send(self, link: str, msg: mavlink.MAVLink_message, out: VehicleOutputs) -> None:
        encoder = self.encoders[link]
        out.frames[link] += msg.pack(encoder)
        encoder.seq = (encoder.seq + 1) % 256


def autopilot_version() -> mavlink.MAVLink_message:
    major, minor, patch = VERSION
    return mavlink.MAVLink_autopilot_version_message(
        CAPABILITIES, major << 24 | minor << 16 | patch << 8 | mavlink.FIRMWARE_VERSION_TYPE_OFFICIAL,
        0, 0, 0, list(b"abyss\0\0\0"), [0] * 8, [0] * 8, 0, 0, 0,
    )  # fmt: skip
