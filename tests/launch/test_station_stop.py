"""A station stops within its bound (5 s after SIGINT) whatever it was doing: here the onshore
station, a real process, blocked in a publish on a satellite link driven at five times its
capacity by an operator tool that floods it with long waypoint lists."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from abyss.bus.session import open_session, zenoh_config
from abyss.common.errors import BusError
from abyss.common.ports import free_port
from abyss.console.op import hand_command
from abyss.interface import keys
from abyss.interface.messages import LinkControl, Waypoints, encode
from abyss.stations.onshore.core import JOIN_WAIT_S

STOP_BOUND_S = 5.0
RATE_BPS = 512_000  # the satellite's rate for this test
WAYPOINTS_BYTES = 1000 * 4 * 8  # the longest list a message carries
SHORE_PERIOD_S = 0.1  # shore sends the latest command once a period: 5x the rate above


@pytest.mark.timeout(120)
def test_a_station_blocked_on_a_saturated_link_stops_within_its_bound(tmp_path: Path) -> None:
    assert WAYPOINTS_BYTES * 8 / SHORE_PERIOD_S >= 5 * RATE_BPS
    system, port = "stoptest", free_port()
    status_path, log_path = tmp_path / "onshore.json", tmp_path / "onshore.log"
    endpoint = f"tcp/127.0.0.1:{port}"
    session = open_session(zenoh_config([endpoint], mode="router"), "test")  # as abyss up's
    with log_path.open("wb") as log:
        station = subprocess.Popen(
            [
                sys.executable,
                "-P",
                "-m",
                "abyss.cli",
                "station",
                "onshore",
                "--system",
                system,
                "--listen",
                "tcp/127.0.0.1:0",
                "--connect",
                endpoint,
                "--status-file",
                str(status_path),
                "--set",
                "onshore.viewer=none",
            ],
            stdout=log,
            stderr=subprocess.STDOUT,
            cwd=tmp_path,
        )
    flooding = threading.Event()
    waypoints = np.tile([0.0, 0.0, -10.0, 0.0], (1000, 1))

    def flood() -> None:
        command_id = 1
        while not flooding.is_set():
            message = Waypoints(command_id, waypoints)
            try:  # shore takes each
                hand_command(session, system, "waypoints", message, "the test's flood")
            except BusError:  # the station stopped: nothing takes it any more
                return
            command_id += 1
            flooding.wait(SHORE_PERIOD_S / 2)

    flooder = threading.Thread(target=flood, daemon=True)
    try:
        up = session.liveliness().declare_subscriber(keys.alive_key(system, "onshore"), history=True)
        assert up.recv() is not None  # blocks until the station's token is seen
        session.put(
            keys.link_key(system, "satellite"),
            encode(LinkControl("", {"rate": f"{RATE_BPS // 1000}kbit"}), 0, time.time()),
        )
        flooder.start()
        # shore sends nothing before it has heard onboard or JOIN_WAIT_S passed; then the queue
        # fills in about half a second; let shore block on it for a while
        time.sleep(JOIN_WAIT_S + 3.0)
        asked_s = time.monotonic()
        station.send_signal(signal.SIGINT)
        station.wait(timeout=30)
        stop_s = time.monotonic() - asked_s
    finally:
        flooding.set()
        if station.poll() is None:
            station.kill()
        if flooder.is_alive():  # its last handover done (or refused: the station gone) first
            flooder.join()
        session.close()
    log_text = log_path.read_text()
    assert station.returncode == 0, log_text
    assert stop_s < STOP_BOUND_S, log_text
    status = json.loads(status_path.read_text())
    satellite = status["links"]["satellite"]
    assert satellite["refused_at_stop"] >= 1, satellite  # it was blocked in a publish when asked
    assert satellite["messages_offered"] >= 3
    assert status["stop_s"] < STOP_BOUND_S


HANGING_STATION = """
import sys, time
from pathlib import Path
import abyss.launch.station as runtime
from abyss.config import Config

def hang(config, bus):  # a station whose work ignores the stop: a call that never returns
    time.sleep(600)

runtime.station_entry = lambda name: hang
runtime.configure_logging()
sys.exit(runtime.run_station("onshore", Config(system="hang"), [], [sys.argv[1]], Path(sys.argv[2])))
"""


@pytest.mark.timeout(120)
def test_a_station_that_hangs_is_cut_at_its_bound_with_its_stacks_and_status(tmp_path: Path) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    session = open_session(zenoh_config([endpoint], mode="router"), "test")
    status_path = tmp_path / "onshore.json"
    station = subprocess.Popen(
        [sys.executable, "-P", "-c", HANGING_STATION, endpoint, str(status_path)],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        cwd=tmp_path,
    )
    try:
        up = session.liveliness().declare_subscriber(keys.alive_key("hang", "onshore"), history=True)
        assert up.recv() is not None
        station.send_signal(signal.SIGUSR1)  # its stacks, asked for (a run that stood still): it goes on
        time.sleep(0.5)
        asked_s = time.monotonic()
        station.send_signal(signal.SIGINT)
        output, _ = station.communicate(timeout=30)
        stop_s = time.monotonic() - asked_s
    finally:
        if station.poll() is None:
            station.kill()
        session.close()
    text = output.decode(errors="replace")
    assert stop_s < STOP_BOUND_S, text
    assert "not stopped 4.5 s after it was asked" in text and "in hang" in text, text  # the stack says where
    assert text.count("Current thread") == 2, text  # every thread's stack: for SIGUSR1, then at the cut
    status = json.loads(status_path.read_text())
    assert status["stop_cut"] is True and status["exit_code"] == 0
