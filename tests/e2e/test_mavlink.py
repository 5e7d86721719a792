"""The BlueROV2 as a MAVLink vehicle (mavlink.enabled), flown by pymavlink as a ground station
is, through the satellite's emulator to the onshore station's endpoint, with MAVProxy watching on
the tether's side at the vessel's (another system id: not the GCS the failsafe watches). It sees
HIGH_LATENCY2 on the satellite until it turns high latency off, then the heartbeat and ArduSub's
modes; arms, holds depth in depth hold (held to the simulation's truth), flies forward on
MANUAL_CONTROL; the satellite dropped for 10 s fires the GCS failsafe (MAVProxy shows it said and
the vehicle disarmed) and its return clears it; a mission uploaded and flown in auto to its last
waypoint ends the run done. Fuzzed bytes on both endpoints are dropped and counted. A ground
station is a real-time party: the run is on the wall clock (time.mode real), every wait an event
with a bound."""

from __future__ import annotations

import json
import os
import random
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import ROOT, Process, Truth, Up, abyss

os.environ["MAVLINK20"] = "1"  # before pymavlink's mavutil picks its dialect: MAVLink 2, as ArduSub
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from abyss.interface import keys
from abyss.mavlink.sitl_json import ServoPacket

pytestmark = pytest.mark.timeout(420)
OUTAGE_S = 10.0
# The longest the satellite's TCP (the link model's transport, linkemu/transport/tcp.py) takes to
# carry traffic again after the outage: its retransmission timer backs off over the outage
# (firing at about 0.7, 2, 5, 10.5, 22, 44, 89, 178 s from its start), the first after the
# restore goes through nine times in ten (the satellite's 5 % loss, each way), and each lost
# doubles the wait: about 1-12 s, and within the bound with four lost in a row (one in ten
# thousand). In 300 outages simulated on the model: median 8 s, 99th percentile 34 s, most 132 s.
RECOVERY_S = 180.0
ROBOT = ROOT / "description" / "models" / "robots" / "bluerov2_heavy_alpha5"
SYSTEM = "e2e-mavlink"


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class GroundStation:
    """pymavlink as a ground station: its heartbeat at 1 Hz and the sticks (MANUAL_CONTROL) at
    10 Hz from a thread of its own, as QGroundControl sends them; system 255, the one the GCS
    failsafe watches."""

    def __init__(self, address: str) -> None:
        self.conn: Any = mavutil.mavlink_connection(
            address, source_system=255, source_component=190, dialect="ardupilotmega"
        )
        self.sticks: list[int] | None = [0, 0, 500, 0]
        self.texts: list[str] = []
        self.lock = threading.Lock()
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._beat, daemon=True)
        self.thread.start()

    def _beat(self) -> None:
        k = 0
        while not self.stop.wait(0.1):
            with self.lock:
                if k % 10 == 0:
                    self.conn.mav.heartbeat_send(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
                if self.sticks is not None:
                    self.conn.mav.manual_control_send(1, *self.sticks, 0)
            k += 1

    def send(self, name: str, *args: Any) -> None:
        with self.lock:
            getattr(self.conn.mav, f"{name}_send")(*args)

    def wait(self, kind: str | list[str], timeout_s: float, holds: Any = lambda m: True) -> Any:
        """The first message of `kind` that `holds` within `timeout_s` (AssertionError if none)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            msg = self.conn.recv_match(type=kind, blocking=True, timeout=0.2)
            if msg is None:
                continue
            if msg.get_type() == "STATUSTEXT":
                self.texts.append(msg.text)
            if holds(msg):
                return msg
        raise AssertionError(f"no {kind} within {timeout_s} s; texts: {self.texts}")

    def text(self, pattern: str, timeout_s: float) -> str:
        return str(self.wait("STATUSTEXT", timeout_s, lambda m: pattern in m.text).text)

    def command(self, command: int, *params: float, timeout_s: float = 10.0) -> int:
        """COMMAND_LONG, sent again each second until answered (the satellite loses packets); its result."""
        padded = [*params, *[0.0] * (7 - len(params))]
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            self.send("command_long", 1, 1, command, 0, *padded)
            try:
                return int(self.wait("COMMAND_ACK", 1.0, lambda m: m.command == command).result)
            except AssertionError:
                continue
        raise AssertionError(f"command {command} not answered within {timeout_s} s")

    def close(self) -> None:
        self.stop.set()
        self.thread.join()
        self.conn.close()


def mavproxy(port: int, cwd: Path) -> Process:
    """MAVProxy as a team runs it, non-interactive, on the vessel's side (system 250)."""
    script = Path(sys.executable).with_name("mavproxy.py")
    command = [
        sys.executable,
        str(script),
        f"--master=udpout:127.0.0.1:{port}",
        "--source-system=250",
        "--non-interactive",
    ]
    return Process(command, cwd, {"MAVLINK20": "1"})


def depth_held(truth: Truth, seconds: float) -> float:
    """How far the true depth moved over the last `seconds` [m]."""
    return float(np.ptp([s.position_m_world[2] for s in truth.since(seconds)]))


def upload(gcs: GroundStation, items: list[tuple[int, int, float]]) -> None:
    """A mission (home first) of waypoints at (degE7, degE7, altitude relative to the surface [m]),
    item by item as the vehicle asks for them."""
    rows = [
        (mavlink.MAV_CMD_DO_SET_HOME if i == 0 else mavlink.MAV_CMD_NAV_WAYPOINT, *item)
        for i, item in enumerate(items)
    ]
    asked = ["MISSION_REQUEST_INT", "MISSION_ACK"]
    deadline = time.monotonic() + RECOVERY_S
    while True:  # the count sent again until answered, as QGroundControl does on a lossy link
        gcs.send("mission_count", 1, 1, len(rows), mavlink.MAV_MISSION_TYPE_MISSION)
        try:
            msg = gcs.wait(asked, 3.0)
            break
        except AssertionError:
            if time.monotonic() > deadline:
                raise
    while True:  # then each item the vehicle asks for (again and again, when one is lost)
        if msg.get_type() == "MISSION_ACK":
            assert msg.type == mavlink.MAV_MISSION_ACCEPTED, msg
            return
        command, lat, lon, alt = rows[msg.seq]
        gcs.send(
            "mission_item_int", 1, 1, msg.seq, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, command,
            0, 1, 0, 0, 0, float("nan"), lat, lon, alt, mavlink.MAV_MISSION_TYPE_MISSION,
        )  # fmt: skip
        msg = gcs.wait(asked, 20.0)


def fuzz(port: int, count: int = 200) -> None:
    """Random bytes, and MAVLink frames cut short or with a bad CRC, at an endpoint."""
    rng = random.Random(7)
    frame = mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GCS, 8, 0, 0, 0, 3).pack(
        mavlink.MAVLink(None, 200, 1)
    )
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for i in range(count):
            kind = i % 3
            data = (
                rng.randbytes(rng.randint(1, 300)) if kind == 0 else frame[: rng.randint(3, len(frame) - 1)]
            )
            if kind == 2:
                data = frame[:-1] + bytes([frame[-1] ^ 0xFF])
            s.sendto(data, ("127.0.0.1", port))


def test_a_ground_station_flies_the_bluerov2_across_the_satellite_as_ardusub(tmp_path: Path) -> None:
    shore_port, vessel_port = free_udp_port(), free_udp_port()
    up = Up(
        tmp_path / "run",
        "--robot", str(ROBOT), "--system", SYSTEM, "--time", "real", "--duration", "240",
        "--viewer", "none", "--record", "none",
        "--set", "mavlink.enabled=true", "--set", f"mavlink.onshore_port={shore_port}",
        "--set", f"mavlink.vessel_port={vessel_port}", "--set", "mission.interventions=[]",
    )  # fmt: skip
    up.wait_up(90.0)
    truth = Truth(up.endpoint, SYSTEM)
    gcs, watcher = GroundStation(f"udpout:127.0.0.1:{shore_port}"), mavproxy(vessel_port, tmp_path)
    link = ("--connect", up.endpoint, "--system", SYSTEM)
    try:
        watcher.wait_for("Detected vehicle 1:1", 30.0)  # the tether's side: a full link from the start
        # the satellite's side is a high-latency link: HIGH_LATENCY2 alone, until turned off
        hl2 = gcs.wait("HIGH_LATENCY2", 30.0)
        assert hl2.type == mavlink.MAV_TYPE_SUBMARINE and hl2.custom_mode == 19  # ArduSub's MANUAL
        assert gcs.command(mavlink.MAV_CMD_CONTROL_HIGH_LATENCY, 0) == mavlink.MAV_RESULT_ACCEPTED
        beat = gcs.wait("HEARTBEAT", 10.0)
        assert beat.autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA and gcs.conn.flightmode == "MANUAL"
        assert gcs.command(mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION) == 0
        # the parameters: ArduSub's defaults, one set (the sticks' failsafe to warn only, so that the
        # satellite's drop below fires the GCS failsafe's disarm, not the pilot input's)
        gcs.send("param_request_read", 1, 1, b"FS_GCS_ENABLE", -1)
        assert gcs.wait("PARAM_VALUE", 10.0, lambda m: m.param_id == "FS_GCS_ENABLE").param_value == 2.0
        gcs.send("param_set", 1, 1, b"FS_PILOT_INPUT", 1.0, mavlink.MAV_PARAM_TYPE_INT8)
        assert gcs.wait("PARAM_VALUE", 10.0, lambda m: m.param_id == "FS_PILOT_INPUT").param_value == 1.0
        # armed, in depth hold: the depth held on the truth
        assert gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mavlink.MAV_RESULT_ACCEPTED
        assert gcs.command(mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 2) == 0
        gcs.wait(
            "HEARTBEAT",
            10.0,
            lambda m: m.custom_mode == 2 and m.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED,
        )
        time.sleep(4.0)  # the truth over a hold, at 20 Hz
        assert depth_held(truth, 3.0) < 0.1, truth.since(3.0)[-1]
        # the sticks: forward at 0.8 until the truth has it 0.3 m on (an event, not a sleep: the
        # sticks cross the satellite), its depth held on the way
        start = truth.since(0.1)[-1].position_m_world.copy()
        gcs.sticks = [800, 0, 500, 0]
        deadline, moved = time.monotonic() + 30.0, np.zeros(3)
        while time.monotonic() < deadline and np.hypot(*moved[:2]) <= 0.3:
            time.sleep(0.1)
            moved = truth.since(0.1)[-1].position_m_world - start
            assert abs(moved[2]) < 0.15, moved
        gcs.sticks = [0, 0, 500, 0]
        assert np.hypot(*moved[:2]) > 0.3 and abs(moved[1]) < 0.1, moved  # forward: the site's x
        # the satellite down for 10 s: the GCS failsafe, seen from the vessel's side
        assert abyss("link", "set", "satellite", "--profile", "outage", *link).returncode == 0
        down_s = time.monotonic()
        watcher.wait_for("AP: MYGCS: 255, heartbeat lost", 10.0)
        watcher.wait_for("DISARMED", 5.0)
        watcher.wait_for("Received 10 parameters", 5.0)  # it read them at the start, as it does
        time.sleep(max(0.0, down_s + OUTAGE_S - time.monotonic()))  # the outage's length: a script's
        assert abyss("link", "set", "satellite", "--profile", "satellite", *link).returncode == 0
        # cleared, disarmed, once the satellite's TCP carries traffic again both ways
        gcs.wait("HEARTBEAT", RECOVERY_S, lambda m: m.system_status == mavlink.MAV_STATE_STANDBY)
        fuzz(shore_port)
        fuzz(vessel_port)
        # a mission: two waypoints 0.6 m on, flown in auto to the last
        here = gcs.wait("GLOBAL_POSITION_INT", 10.0)
        north, east = 0.6 / 111_000 * 1e7, 0.6 / 81_000 * 1e7  # 0.6 m, in degE7, at 43 degrees
        depth = here.relative_alt / 1000.0
        upload(gcs, [(here.lat, here.lon, 0.0), (round(here.lat + north), here.lon, depth),
                     (round(here.lat + north), round(here.lon + east), depth)])  # fmt: skip
        assert gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mavlink.MAV_RESULT_ACCEPTED
        assert gcs.command(mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 3) == 0
        gcs.wait("MISSION_ITEM_REACHED", 60.0, lambda m: m.seq == 2)
        assert up.wait(60.0) == 0, up.output()  # the mission done ends the run
    finally:
        gcs.close()
        watcher.process.terminate()
        watcher.wait(20.0)
        truth.close()
    summary = up.summary()
    assert summary["verdict"] == "done" and summary["mission"]["waypoints_total"] == 2, summary["mission"]
    for station, key in (("onshore", "onshore/mavlink/in"), ("vessel", "vessel/mavlink/in")):
        rejected = summary["stations"][station]["rejected"].get(f"abyss/{SYSTEM}/{key}", 0)
        assert rejected >= 100, (
            station,
            summary["stations"][station]["rejected"],
        )  # each dropped and counted
    assert keys.spec("onboard", "mavlink/out").key(SYSTEM) in summary["stations"]["vessel"]["received"]


ARDUSUB = os.environ.get("ABYSS_ARDUSUB", "")  # a team's ArduSub SITL binary (build/sitl/bin/ardusub)


@pytest.mark.skipif(
    not (ARDUSUB and os.access(ARDUSUB, os.X_OK)),
    reason="no ArduSub SITL binary (set ABYSS_ARDUSUB to one built with ./waf configure --board sitl "
    "&& ./waf sub): none could be built on this machine, docs/mavlink.md says why",
)
def test_ardusub_arms_and_holds_depth_on_abysss_physics(tmp_path: Path) -> None:
    """ArduSub itself on `abyss sitl`'s physics (the JSON backend), the BlueROV2 Heavy's vectored
    6-DoF frame: armed from pymavlink on ArduSub's own port, in depth hold its depth held."""
    port = free_udp_port()
    sitl = subprocess.Popen(
        [sys.executable, "-m", "abyss.cli", "sitl", "--robot", str(ROBOT), "--port", str(port)],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    defaults = tmp_path / "abyss.parm"
    defaults.write_text(f"FRAME_CONFIG 2\nSIM_JSON_PORT {port}\nFS_PILOT_INPUT 0\nARMING_CHECK 0\n")
    ardusub = subprocess.Popen(
        [ARDUSUB, "--model", "JSON:127.0.0.1", "--defaults", str(defaults), "--speedup", "1", "-I0",
         "--home", "43.2951,5.3700,0,90"],
        cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    gcs = None
    try:
        gcs = GroundStation("tcp:127.0.0.1:5760")
        gcs.sticks = None  # FS_PILOT_INPUT 0: no sticks needed
        gcs.wait("HEARTBEAT", 60.0, lambda m: m.type == mavlink.MAV_TYPE_SUBMARINE)
        assert (
            gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1, timeout_s=30.0)
            == mavlink.MAV_RESULT_ACCEPTED
        )
        assert gcs.command(mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 2) == 0
        depths = [
            gcs.wait("GLOBAL_POSITION_INT", 5.0).relative_alt / 1000.0 for _ in range(50)
        ]  # about 10 s at ArduSub's default stream rate
        assert np.ptp(depths) < 0.2, depths
    finally:
        if gcs is not None:
            gcs.close()
        ardusub.terminate()
        sitl.terminate()
        sitl.communicate(timeout=20)
        ardusub.communicate(timeout=20)


def free_tcp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class ArduPilotFrames:
    """ArduPilot's JSON side in its place (the physics' contract: tests/stations/simulation/
    test_json_backend.py), paced to the wall clock at 50 frames a second with the motors neutral."""

    def __init__(self, port: int) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.settimeout(1.0)
        self.port, self.count, self.timestamps = port, 0, [0.0]
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self.stop.wait(0.02):
            self.count += 1
            self.sock.sendto(ServoPacket(50, self.count, (1500,) * 16).pack(), ("127.0.0.1", self.port))
            try:
                line = self.sock.recvfrom(4096)[0]
            except TimeoutError:  # the station not up yet: ArduPilot sends again
                continue
            self.timestamps.append(float(json.loads(line)["timestamp"]))

    def close(self) -> None:
        self.stop.set()
        self.thread.join()
        self.sock.close()


def test_with_ardusub_as_the_autopilot_onboard_routes_its_mavlink_and_hands_it_the_missions_waypoints(
    tmp_path: Path,
) -> None:
    """mavlink.autopilot: the simulation's physics stepped by ArduPilot's JSON frames (a client in
    its place), onboard as the companion computer: a ground station on shore and ArduSub's MAVLink
    (pymavlink in its place, serving TCP as ArduSub's SITL does) hear each other through the
    satellite's emulator, and the mission's first waypoint reaches ArduSub as a guided target in
    the site's north-east-down, ArduSub armed and put in GUIDED first."""
    shore_port, vessel_port, json_port, autopilot_port = (
        free_udp_port(),
        free_udp_port(),
        free_udp_port(),
        free_tcp_port(),
    )
    autopilot: Any = mavutil.mavlink_connection(
        f"tcpin:127.0.0.1:{autopilot_port}", source_system=1, source_component=1, dialect="ardupilotmega"
    )
    up = Up(
        tmp_path / "run",
        "--robot", str(ROBOT), "--system", "e2e-ardusub", "--time", "real", "--duration", "60",
        "--viewer", "none", "--record", "none", "--keep-running",
        "--set", "mavlink.enabled=true", "--set", f"mavlink.onshore_port={shore_port}",
        "--set", f"mavlink.vessel_port={vessel_port}", "--set", f"mavlink.json_port={json_port}",
        "--set", f"mavlink.autopilot=tcp:127.0.0.1:{autopilot_port}", "--set", "mission.interventions=[]",
    )  # fmt: skip
    frames = ArduPilotFrames(json_port)
    gcs = None
    try:
        up.wait_up(90.0)
        truth = Truth(up.endpoint, "e2e-ardusub")
        gcs = GroundStation(f"udpout:127.0.0.1:{shore_port}")
        wanted = {"SET_MODE", "COMMAND_LONG", "SET_POSITION_TARGET_LOCAL_NED", "HEARTBEAT"}
        got: dict[str, Any] = {}
        deadline = time.monotonic() + 40.0
        while time.monotonic() < deadline and not wanted <= got.keys():
            autopilot.mav.heartbeat_send(
                mavlink.MAV_TYPE_SUBMARINE, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 19, 3
            )
            while (msg := autopilot.recv_msg()) is not None:
                if msg.get_type() != "HEARTBEAT" or msg.get_srcSystem() == 255:  # the shore's, routed
                    got.setdefault(msg.get_type(), msg)
            time.sleep(0.2)
        assert wanted <= got.keys(), got.keys()
        assert (
            got["SET_MODE"].custom_mode == 4
            and got["COMMAND_LONG"].command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM
        )
        target = got["SET_POSITION_TARGET_LOCAL_NED"]
        first = np.array(load_config_mission_first())
        assert (target.x, target.y, target.z) == pytest.approx(
            (first[1], first[0], -first[2]), abs=1e-3
        )  # x east
        beat = gcs.wait("HEARTBEAT", 15.0, lambda m: m.get_srcSystem() == 1 and m.custom_mode == 19)
        assert beat.type == mavlink.MAV_TYPE_SUBMARINE  # ArduSub's, across the satellite
        deadline = time.monotonic() + 20.0  # the frames step the physics, and the truth is of it
        while time.monotonic() < deadline and truth.since(0.1)[-1].sim_time_s < 3.0:
            time.sleep(0.2)
        assert truth.since(0.1)[-1].sim_time_s >= 3.0
        assert truth.since(0.1)[-1].sim_time_s == pytest.approx(frames.timestamps[-1], abs=0.5)
        truth.close()
        assert up.interrupt() in ("interrupted", "done")
    finally:
        frames.close()
        if gcs is not None:
            gcs.close()
        autopilot.close()


def load_config_mission_first() -> tuple[float, float, float, float]:
    """The BlueROV2's package's mission's first waypoint [m, world], as the run flies it."""
    from abyss.config import load

    return load(None, [f"simulation.robot={ROBOT}"]).mission.waypoints[0]
