"""Onboard's MAVLink side (mavlink.vehicle) against pymavlink's encoding, as a ground station's
frames reach it: arming, ArduSub's modes, the sticks onto onboard's goals, the GCS and pilot-input
failsafes as ArduSub runs them, the high-latency link, the parameter and mission protocols, and
bad bytes dropped with their reasons."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from abyss.config import Config, load
from abyss.interface.messages import NavState, OperatorMode, Telemetry, Waypoints
from abyss.mavlink.ardusub import SubMode
from abyss.mavlink.vehicle import MavlinkVehicle, VehicleOutputs

START = np.array([1.5, 0.0, -8.5])


@pytest.fixture(scope="module")
def config() -> Config:
    return load(None, ["mavlink.enabled=true", "time.mode=real"])


class Gcs:
    """A ground station's encoder (system 255), the vehicle, and what came back, parsed."""

    def __init__(self, config: Config) -> None:
        self.vehicle = MavlinkVehicle(config, 0.0)
        self.encoder = mavlink.MAVLink(None, 255, 190)
        self.parser = {link: mavlink.MAVLink(None) for link in ("tether", "satellite")}
        self.nav = NavState(START.copy(), np.array([1.0, 0.0, 0.0, 0.0]), np.zeros(3), np.zeros(3), 1.0)

    def frames(self, *messages: mavlink.MAVLink_message) -> bytes:
        data = b""
        for message in messages:
            data += message.pack(self.encoder)
            self.encoder.seq = (self.encoder.seq + 1) % 256
        return data

    def say(self, now_s: float, *messages: mavlink.MAVLink_message, link: str = "tether") -> VehicleOutputs:
        """`messages` to the vehicle, then a control period at `now_s`: what it sent and decided."""
        out = VehicleOutputs()
        assert self.vehicle.receive(link, self.frames(*messages), now_s, out) == []
        self.vehicle.step(now_s, None, [self.nav], out)
        return out

    def heard(self, out: VehicleOutputs, link: str = "tether") -> list[mavlink.MAVLink_message]:
        return list(self.parser[link].parse_buffer(bytes(out.frames[link])) or [])

    def command(self, now_s: float, command: int, *params: float) -> tuple[VehicleOutputs, int]:
        padded = [*params, *[0.0] * (7 - len(params))]
        out = self.say(now_s, mavlink.MAVLink_command_long_message(1, 1, command, 0, *padded))
        (ack,) = [m for m in self.heard(out) if m.get_type() == "COMMAND_ACK" and m.command == command]
        return out, ack.result


def beat() -> mavlink.MAVLink_message:
    return mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3)


def sticks(x: int = 0, y: int = 0, z: int = 500, r: int = 0) -> mavlink.MAVLink_message:
    return mavlink.MAVLink_manual_control_message(1, x, y, z, r, 0)


def texts(messages: list[mavlink.MAVLink_message]) -> list[str]:
    return [m.text for m in messages if m.get_type() == "STATUSTEXT"]


def test_the_heartbeat_says_a_submarine_in_ardusubs_modes_armed_as_commanded(config: Config) -> None:
    gcs = Gcs(config)
    (hb,) = [m for m in gcs.heard(gcs.say(0.0, beat())) if m.get_type() == "HEARTBEAT"]
    assert (hb.type, hb.autopilot, hb.custom_mode) == (
        mavlink.MAV_TYPE_SUBMARINE,
        mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
        19,
    )
    assert (
        not hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        and hb.system_status == mavlink.MAV_STATE_STANDBY
    )
    out, result = gcs.command(0.1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert result == mavlink.MAV_RESULT_ACCEPTED and "Arming motors" in texts(gcs.heard(out))
    assert [c.mode for c in out.commands if isinstance(c, OperatorMode)] == ["auto"]  # onboard flies
    out, result = gcs.command(0.2, mavlink.MAV_CMD_DO_SET_MODE, 1, SubMode.CIRCLE)
    assert result == mavlink.MAV_RESULT_UNSUPPORTED and any("CIRCLE" in t for t in texts(gcs.heard(out)))
    _, result = gcs.command(0.3, mavlink.MAV_CMD_DO_SET_MODE, 1, SubMode.ALT_HOLD)
    assert result == mavlink.MAV_RESULT_ACCEPTED
    out = gcs.say(1.1, beat(), sticks())
    (hb,) = [m for m in gcs.heard(out) if m.get_type() == "HEARTBEAT"]
    assert hb.custom_mode == SubMode.ALT_HOLD and hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    assert hb.system_status == mavlink.MAV_STATE_ACTIVE
    out, result = gcs.command(1.2, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0)
    assert [c.mode for c in out.commands if isinstance(c, OperatorMode)] == ["hold"]  # disarmed: held


def test_the_sticks_set_a_goal_ahead_at_their_speed_and_a_centred_stick_holds(config: Config) -> None:
    gcs = Gcs(config)
    gcs.command(0.0, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    gcs.command(0.0, mavlink.MAV_CMD_DO_SET_MODE, 1, SubMode.ALT_HOLD)
    out = gcs.say(0.1, sticks(x=1000, z=560))  # forward at full, the throttle within THR_DZ (100)
    (goal,) = [c for c in out.commands if isinstance(c, Waypoints)]
    o = config.onboard
    ahead_m = 0.5 * o.max_speed_mps / o.kp_position  # JS_GAIN_DEFAULT 0.5 of the speed limit
    assert goal.waypoints[0][:3] == pytest.approx(
        START + np.array([ahead_m, 0.0, 0.0])
    )  # depth held in the dead band
    assert goal.command_id in gcs.vehicle.pilot_goals  # a pilot's goal, not a mission
    gcs.nav = NavState(
        START + np.array([0.3, 0.0, 0.0]), gcs.nav.orientation_wxyz_world, np.zeros(3), np.zeros(3), 2.0
    )
    out = gcs.say(0.2, sticks(x=0, y=-1000))  # forward centred: held where it centred; left at full
    (goal,) = [c for c in out.commands if isinstance(c, Waypoints)]
    assert goal.waypoints[0][0] == pytest.approx(START[0] + 0.3) and goal.waypoints[0][1] == pytest.approx(
        ahead_m
    )
    out = gcs.say(0.3, sticks())
    assert not [
        c for c in gcs.say(0.4, sticks()).commands if isinstance(c, Waypoints)
    ]  # unchanged: not resent


def test_the_gcs_failsafe_disarms_once_and_clears_when_the_heartbeat_returns(config: Config) -> None:
    gcs = Gcs(config)
    gcs.say(0.0, beat(), sticks(), mavlink.MAVLink_param_set_message(1, 1, b"FS_PILOT_INPUT", 1.0, 2))
    gcs.command(0.1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    out = gcs.say(4.9)  # 4.8 s of silence: FS_GCS_TIMEOUT is 5 (the sticks' failsafe only warns)
    assert gcs.vehicle.armed and not any("MYGCS" in t for t in texts(gcs.heard(out)))
    out = gcs.say(5.1)
    said = gcs.heard(out)
    assert "MYGCS: 255, heartbeat lost" in texts(said) and "Disarming motors" in texts(said)
    assert not gcs.vehicle.armed and gcs.vehicle.system_status == mavlink.MAV_STATE_CRITICAL
    gcs.say(6.0, sticks())  # the sticks of its ground station count as its heartbeat, as ArduSub's
    assert (
        gcs.vehicle.system_status == mavlink.MAV_STATE_STANDBY and not gcs.vehicle.armed
    )  # cleared, still disarmed


def test_another_systems_sticks_are_not_taken(config: Config) -> None:
    gcs = Gcs(config)
    other = mavlink.MAVLink(None, 250, 190)  # a companion, not SYSID_MYGCS
    gcs.vehicle.receive("tether", sticks(x=1000).pack(other), 0.0, VehicleOutputs())
    assert not gcs.vehicle.sticks.any() and gcs.vehicle.gcs_seen_s is None


def test_the_pilot_input_failsafe_warns_once_then_disarms_as_set(config: Config) -> None:
    gcs = Gcs(config)
    gcs.say(0.0, beat(), sticks())
    gcs.command(0.1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    out = gcs.say(3.2, beat())  # FS_PILOT_TIMEOUT 3 s, FS_PILOT_INPUT 2 (disarm): ArduSub's defaults
    assert "Lost manual control" in texts(gcs.heard(out)) and not gcs.vehicle.armed
    out = gcs.say(3.5, beat())
    assert "Lost manual control" not in texts(gcs.heard(out))  # once
    gcs.say(3.6, beat(), sticks(), mavlink.MAVLink_param_set_message(1, 1, b"FS_PILOT_INPUT", 1.0, 2))
    gcs.command(3.7, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    out = gcs.say(7.0, beat())
    assert "Lost manual control" in texts(gcs.heard(out)) and gcs.vehicle.armed  # warn only


def test_the_satellites_side_hears_high_latency2_every_5_s_until_turned_off(config: Config) -> None:
    gcs = Gcs(config)
    kinds = [
        m.get_type() for t in np.arange(0.0, 10.0, 0.05) for m in gcs.heard(gcs.say(float(t)), "satellite")
    ]
    assert kinds.count("HIGH_LATENCY2") == 2 and "HEARTBEAT" not in kinds and "ATTITUDE" not in kinds
    out = gcs.say(
        10.0,
        mavlink.MAVLink_command_long_message(
            1, 1, mavlink.MAV_CMD_CONTROL_HIGH_LATENCY, 0, 0, 0, 0, 0, 0, 0, 0
        ),
        link="satellite",
    )
    heard = gcs.heard(out, "satellite")
    assert [m.result for m in heard if m.get_type() == "COMMAND_ACK"] == [mavlink.MAV_RESULT_ACCEPTED]
    kinds = [
        m.get_type() for t in np.arange(10.05, 12.0, 0.05) for m in gcs.heard(gcs.say(float(t)), "satellite")
    ]
    assert "HEARTBEAT" in kinds and "GLOBAL_POSITION_INT" in kinds and "HIGH_LATENCY2" not in kinds


def test_parameters_are_listed_read_and_set_within_their_range(config: Config) -> None:
    gcs = Gcs(config)
    listed = [
        m
        for m in gcs.heard(gcs.say(0.0, mavlink.MAVLink_param_request_list_message(1, 1)))
        if m.get_type() == "PARAM_VALUE"
    ]
    assert [m.param_index for m in listed] == list(range(len(listed))) and {
        m.param_count for m in listed
    } == {len(listed)}
    values = {m.param_id: m.param_value for m in listed}
    assert values["FS_GCS_ENABLE"] == 2 and values["FS_GCS_TIMEOUT"] == 5 and values["SYSID_MYGCS"] == 255
    assert (
        values["FRAME_CONFIG"] == 7
    )  # the work-class's six thrusters: custom, not the Heavy's vectored 6-DoF
    out = gcs.say(0.1, mavlink.MAVLink_param_set_message(1, 1, b"FS_GCS_TIMEOUT", 500.0, 9))
    (value,) = [m for m in gcs.heard(out) if m.get_type() == "PARAM_VALUE"]
    assert value.param_value == 5.0 and any("out of range" in t for t in texts(gcs.heard(out)))
    out = gcs.say(0.2, mavlink.MAVLink_param_set_message(1, 1, b"FS_GCS_TIMEOUT", 2.5, 9))
    assert gcs.vehicle.params["FS_GCS_TIMEOUT"] == 2.5
    assert not gcs.heard(gcs.say(0.3, mavlink.MAVLink_param_set_message(1, 1, b"NO_SUCH", 1.0, 9)))[:0]


def test_a_mission_uploaded_item_by_item_is_flown_in_auto_and_its_items_reported_reached(
    config: Config,
) -> None:
    gcs = Gcs(config)
    g = gcs.vehicle.geodesy
    lat, lon, _ = g.geodetic_of(START)
    wanted = [START + np.array([1.0, 0.0, 0.0]), START + np.array([1.0, 1.0, -0.5])]
    items = [(lat, lon, 0.0), *((*g.geodetic_of(w)[:2], float(w[2])) for w in wanted)]
    out = gcs.say(0.0, mavlink.MAVLink_mission_count_message(1, 1, len(items), 0))
    for step in range(len(items)):
        (request,) = [m for m in gcs.heard(out) if m.get_type() == "MISSION_REQUEST_INT"]
        assert request.seq == step
        la, lo, alt = items[request.seq]
        item = mavlink.MAVLink_mission_item_int_message(
            1, 1, request.seq, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, mavlink.MAV_CMD_NAV_WAYPOINT,
            0, 1, 0, 0, 0, math.nan, round(la * 1e7), round(lo * 1e7), alt, 0,
        )  # fmt: skip
        out = gcs.say(0.1 + step, item)
    assert [m.type for m in gcs.heard(out) if m.get_type() == "MISSION_ACK"] == [mavlink.MAV_MISSION_ACCEPTED]
    gcs.say(4.9, sticks())  # the pilot's input, or its failsafe disarms (FS_PILOT_INPUT 2)
    gcs.command(5.0, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    out, _ = gcs.command(5.1, mavlink.MAV_CMD_DO_SET_MODE, 1, SubMode.AUTO)
    (flown,) = [c for c in out.commands if isinstance(c, Waypoints)]
    assert flown.waypoints[:, :3] == pytest.approx(np.array(wanted), abs=1e-3)  # home not flown
    assert flown.command_id not in gcs.vehicle.pilot_goals
    reached = Telemetry(
        **{**_telemetry(), "command_id": flown.command_id, "waypoint_index": 1, "waypoints_total": 2}
    )
    out = VehicleOutputs()
    gcs.vehicle.step(5.3, reached, [gcs.nav], out)
    assert [m.seq for m in gcs.heard(out) if m.get_type() == "MISSION_ITEM_REACHED"] == [1]
    out = gcs.say(5.4, mavlink.MAVLink_mission_request_list_message(1, 1, 0))
    assert [m.count for m in gcs.heard(out) if m.get_type() == "MISSION_COUNT"] == [3]


def test_an_item_not_come_is_asked_for_again(config: Config) -> None:
    gcs = Gcs(config)
    gcs.say(0.0, mavlink.MAVLink_mission_count_message(1, 1, 2, 0))
    out = gcs.say(1.2)
    assert [m.seq for m in gcs.heard(out) if m.get_type() == "MISSION_REQUEST_INT"] == [0]


def test_bad_bytes_are_dropped_with_their_reason_and_the_good_frames_taken(config: Config) -> None:
    gcs = Gcs(config)
    out = VehicleOutputs()
    data = b"\x00garbage" + gcs.frames(
        mavlink.MAVLink_command_long_message(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
    )
    bad = gcs.vehicle.receive("tether", data, 0.0, out)
    assert bad and all(reason.startswith("MAVLink: ") for reason in bad)
    assert gcs.vehicle.armed and gcs.vehicle.malformed == len(bad)


def _telemetry() -> dict[str, object]:
    return dict(
        position_m_world=START, yaw_rad=0.0, mode="moving", command_id=-1, waypoint_index=0,
        waypoints_total=0,
        position_error_m_world=np.zeros(3), heading_error_rad=0.0, arm_mode="idle", arm_command_id=-1,
        ee_position_error_m_world=np.zeros(3), ee_orientation_error_rad=0.0, ee_position_m_world=np.zeros(3),
        ee_orientation_wxyz_world=np.array([1.0, 0, 0, 0]), arm_positions_rad=np.zeros(6), failsafe="",
        failsafe_events=0, sim_time_s=5.0,
    )  # fmt: skip
