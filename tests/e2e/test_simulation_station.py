"""The simulation station alone, driven by a test that plays onboard over real Zenoh, as a
team would drive it with their own onboard software."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import msgpack
import numpy as np
import pytest
import zenoh
from conftest import ROOT, abyss

from abyss.bus.session import open_session, zenoh_config
from abyss.common.ports import free_port
from abyss.common.workers import BACKGROUND_NICE
from abyss.interface import keys
from abyss.interface.images import decode_image
from abyss.interface.messages import (
    Image,
    NavState,
    SimulationControl,
    SimulationStatus,
    VelocityRef,
    decode,
    encode,
)

pytestmark = pytest.mark.timeout(120)
SYSTEM = "e2e-sim"
REALTIME_ALLOWED = os.geteuid() == 0  # CAP_SYS_NICE; CI runs as root


def schedulers(pid: int) -> dict[int, int]:
    """Each thread of process `pid`: its scheduling policy."""
    return {int(thread): os.sched_getscheduler(int(thread)) for thread in os.listdir(f"/proc/{pid}/task")}


def children(pid: int) -> list[int]:
    """The processes that process `pid`'s threads started."""
    return [
        int(child)
        for thread in os.listdir(f"/proc/{pid}/task")
        for child in Path(f"/proc/{pid}/task/{thread}/children").read_text().split()
    ]


class Observed:
    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.truth: list[NavState] = []
        self.status: list[SimulationStatus] = []
        self.images: dict[str, list[Image]] = {}

    def on_sample(self, sample: zenoh.Sample) -> None:
        message = decode(str(sample.key_expr), sample.payload.to_bytes()).message
        with self.lock:
            if isinstance(message, NavState):
                self.truth.append(message)
            elif isinstance(message, SimulationStatus):
                self.status.append(message)
            elif isinstance(message, Image):
                self.images.setdefault(message.camera, []).append(message)


def test_simulation_station_commands_watchdog_faults_and_cameras(tmp_path: Path) -> None:
    port = free_port()
    status_file = tmp_path / "simulation.json"
    station = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "abyss.cli",
            "station",
            "simulation",
            "--system",
            SYSTEM,
            "--listen",
            f"tcp/127.0.0.1:{port}",
            "--status-file",
            str(status_file),
            "--set",
            "simulation.camera_rate_hz=2",
            "--set",
            "simulation.low_level=dynamic",
        ],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
    )
    session = open_session(zenoh_config(connect=[f"tcp/127.0.0.1:{port}"]), "test onboard")
    observed = Observed()
    watched = (
        keys.truth_key(SYSTEM),
        keys.simulation_status_key(SYSTEM),
        keys.key(SYSTEM, "simulation", "camera", "*"),
    )
    subscribers = [session.declare_subscriber(k, observed.on_sample) for k in watched]
    command_key = keys.spec("onboard", "cmd/vehicle_velocity").key(SYSTEM)
    try:
        deadline = time.monotonic() + 30
        while not observed.truth and time.monotonic() < deadline:
            time.sleep(0.1)
        assert observed.truth, "no ground truth from the simulation station"
        forward = encode(VelocityRef(np.array([0.3, 0.0, 0.0]), 0.0), 0, time.time())
        for i in range(80):  # 4 s of commands at 20 Hz, as onboard sends them
            session.put(command_key, encode(VelocityRef(np.array([0.3, 0.0, 0.0]), 0.0), i, time.time()))
            time.sleep(0.05)
        with observed.lock:
            moving = observed.truth[-1].velocity_mps_body[0]
        assert moving > 0.2
        time.sleep(3.0)  # commands stopped: the watchdog (0.5 s) holds the vehicle still
        with observed.lock:
            held = observed.truth[-1].velocity_mps_body[0]
        assert abs(held) < 0.03

        envelope = msgpack.unpackb(forward)
        nan = np.array([np.nan, 0, 0]).tobytes()
        for bad in (
            {"linear_mps_body": {"dtype": "<f8", "shape": [3], "data": nan}},  # NaN
            {"linear_mps_body": {"dtype": "<f8", "shape": [2], "data": bytes(16)}},  # shape
            {"yaw_rate_radps": 1e6},
        ):  # absurd magnitude
            session.put(command_key, msgpack.packb({**envelope, "body": {**envelope["body"], **bad}}))
        control_key = keys.simulation_control_key(SYSTEM)
        injected = abyss(
            "fault", "thruster", "thr_vl", "0.5", "--connect", f"tcp/127.0.0.1:{port}", "--system", SYSTEM
        )
        assert injected.returncode == 0 and "thruster/thr_vl" in injected.stdout, injected.stderr
        session.put(control_key, encode(SimulationControl("thruster", "thr_nope", 0.5), 1, time.time()))
        time.sleep(1.5)
        with observed.lock:
            status = observed.status[-1]
            images = {name: list(frames) for name, frames in observed.images.items()}
        assert status.faults == {"thruster/thr_vl": 0.5}
        assert 0.8 < status.realtime_factor < 1.2
        assert set(images) == {"cam_left", "cam_right", "cam_depth"}
        rgb = decode_image(images["cam_left"][-1])
        depth = decode_image(images["cam_depth"][-1])
        assert rgb.shape == (480, 640, 3) and rgb.std() > 20
        assert depth.shape == (480, 640) and 1.0 < float(np.median(depth)) < 30.0
        if REALTIME_ALLOWED:  # the physics' process at real-time priority, its sensors' below it
            assert set(schedulers(station.pid).values()) == {os.SCHED_FIFO}
            sensors = children(station.pid)
            assert len(sensors) == 2  # the cameras' and the sonar's
            for sensor in sensors:
                # the normal scheduler (Mesa puts its shader compiler's threads in its batch class)
                assert set(schedulers(sensor).values()) <= {os.SCHED_OTHER, os.SCHED_BATCH, os.SCHED_IDLE}
                assert os.getpriority(os.PRIO_PROCESS, sensor) == BACKGROUND_NICE
    finally:
        for s in subscribers:
            s.undeclare()
        session.close()
        station.send_signal(signal.SIGINT)
        output = station.communicate(timeout=30)[0].decode()
    assert station.returncode == 0, output
    counts = json.loads(status_file.read_text())
    assert counts["rejected"][command_key] == 3
    assert counts["rejected"][keys.simulation_control_key(SYSTEM)] == 1
    assert counts["scheduler"] == (
        "fifo 10" if REALTIME_ALLOWED else "normal (not permitted here (Operation not permitted))"
    )
    assert "thr_nope" in output and "not one of" in output
