"""`abyss op` against a running system: commands go down through shore, the satellite, the
vessel and the tether, onboard answers each with its fate, and what it takes changes the
vehicle's goal; text that does not parse is refused before anything is sent."""

from __future__ import annotations

import re
import threading
import time
from pathlib import Path

import pytest
import zenoh
from conftest import Up, abyss

from abyss.bus.session import open_session, zenoh_config
from abyss.interface import keys
from abyss.interface.messages import Telemetry, decode

pytestmark = pytest.mark.timeout(150)
SYSTEM = "e2e-op"


class TelemetryOnShore:
    """The telemetry that reached shore, as the operator sees it."""

    def __init__(self, endpoint: str) -> None:
        self.latest: Telemetry | None = None
        self.lock = threading.Lock()
        self.session = open_session(zenoh_config(connect=[endpoint], mode="client"), "test")
        self.subscriber = self.session.declare_subscriber(
            keys.spec("vessel", "telemetry").key(SYSTEM), self._on_sample
        )

    def _on_sample(self, sample: zenoh.Sample) -> None:
        message = decode(str(sample.key_expr), sample.payload.to_bytes(), Telemetry).message
        assert isinstance(message, Telemetry)
        with self.lock:
            self.latest = message

    def wait_for(self, what: str, check: object, timeout_s: float = 20.0) -> Telemetry:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with self.lock:
                t = self.latest
            if t is not None and check(t):  # type: ignore[operator]
                return t
            time.sleep(0.1)
        raise AssertionError(f"telemetry never showed {what}; last: {self.latest}")

    def close(self) -> None:
        self.subscriber.undeclare()
        self.session.close()


def test_operator_commands_are_answered_and_change_the_vehicle_goal(tmp_path: Path) -> None:
    up = Up(tmp_path / "run", "--keep-running", "--duration", "90", "--system", SYSTEM, "--viewer", "none")
    up.wait_up()
    link = ("--connect", up.endpoint, "--system", SYSTEM)
    shore = TelemetryOnShore(up.endpoint)
    try:
        taken = abyss("op", "waypoints", "1.0,0.5,-7.2,0.2; 1.5,0.5,-7.2,0.2", *link)
        assert taken.returncode == 0, taken.stdout + taken.stderr
        command_id = int(re.search(r"waypoints command (\d+): taken by onboard", taken.stdout).group(1))
        t = shore.wait_for("the new waypoints", lambda t: t.command_id == command_id)
        assert t.waypoints_total == 2

        refused = abyss("op", "arm", "9.0,0.0,-7.0,0,0,0", *link)  # 7 m beyond the vehicle's last waypoint
        assert refused.returncode == 1, refused.stdout + refused.stderr
        assert "refused by onboard: out of reach" in refused.stdout
        into_seabed = abyss("op", "waypoints", "2.0,0.0,-9.8,0", *link)
        assert into_seabed.returncode == 1 and "obstacle 1" in into_seabed.stdout, into_seabed.stdout

        hold = abyss("op", "mode", "hold", *link)
        assert hold.returncode == 0, hold.stdout + hold.stderr
        t = shore.wait_for("operator hold", lambda t: t.operator_mode == "hold")
        assert t.failsafe == "operator hold" and t.mode == "hold"
        resumed = abyss("op", "mode", "auto", *link)
        assert resumed.returncode == 0
        shore.wait_for("auto again", lambda t: t.operator_mode == "auto" and t.mode != "hold")

        for text, field in (("1,2", "waypoint 0"), ("1,2,3,x", "waypoint 0"), ("", "waypoints")):
            bad = abyss("op", "waypoints", text, *link)
            assert bad.returncode == 2 and f"abyss: {field}:" in bad.stderr, bad.stderr
        bad_mode = abyss("op", "mode", "fly", *link)
        assert bad_mode.returncode == 2 and "not one of hold, auto, teleop" in bad_mode.stderr
    finally:
        shore.close()
    up.interrupt()
