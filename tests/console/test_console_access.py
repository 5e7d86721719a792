"""The pilot's console without a running system: its real HTTP server over a real Zenoh session.
Bound where others reach it, it asks for the operator's token and sends nothing without it; a
second console on the same shore sees the first one's commands and who sent them; the telemetry's
changes that the pilot must be told become alerts."""

from __future__ import annotations

import contextlib
import http.client
import io
import json
import logging
import queue
import re
import signal
import ssl
import subprocess
import sys
import time
import types
import urllib.error
import urllib.request
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest
import zenoh

from abyss.bus import description
from abyss.bus.session import Bus, message_of, open_session, zenoh_config
from abyss.cli.system import _with_console
from abyss.common.errors import BusError, ConfigError
from abyss.common.ports import free_port
from abyss.config import Config
from abyss.console.access import HEADER, Access, token_of
from abyss.console.op import hand_command, sender_of
from abyss.console.pilot import alerts_of
from abyss.console.server import Console
from abyss.description.robot import robot_at
from abyss.description.site import site_at
from abyss.interface import keys
from abyss.interface.messages import TOOL_COMMANDS, OperatorMode, ShoreEvent, Telemetry, Waypoints, encode
from abyss.interface.system_description import description_payload
from abyss.security import certs
from abyss.security.certs import CertFiles

PANEL = site_at("").panel  # the shipped site's: what these systems run

SYSTEM = "console-test"
WAIT_S = 10.0


@pytest.fixture
def shore() -> Iterator[tuple[zenoh.Session, zenoh.Session]]:
    """Two sessions on one shore network, as `abyss up`'s router and a tool beside it; on the
    router, the onshore station's side of the operator keys, taking the tools' commands."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = open_session(zenoh_config([endpoint], mode="router"), "the test's shore")
    tool = open_session(zenoh_config([], [endpoint], mode="peer"), "the test's tool")
    onshore = taker(router)
    try:
        yield router, tool
    finally:
        onshore.close()
        tool.close()
        router.close()


def taker(session: zenoh.Session) -> Bus:
    """The onshore station's bus as it takes the operator tools' commands (stations/onshore)."""
    bus = Bus(SYSTEM, "onshore", session)
    for topic, message in TOOL_COMMANDS:
        bus.take_key(keys.operator_key(SYSTEM, topic), message)
    return bus


def test_a_command_is_handed_to_shore_once_and_put_out_as_taken() -> None:
    """The tool hands its command over once and learns that shore took it (shore alone resends
    it, down the satellite); every listener on the key sees it as taken, with its sender; a
    malformed one is refused with the reason and counted, and with no onshore station it is said so."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = open_session(zenoh_config([endpoint], mode="router"), "the test's shore")
    tool = open_session(zenoh_config([], [endpoint], mode="peer"), "the test's tool")
    onshore = taker(router)
    key = keys.operator_key(SYSTEM, "mode")
    seen: queue.Queue[tuple[str, bool]] = queue.Queue()
    subscriber = tool.declare_subscriber(key, lambda sample: seen.put(sender_of(sample)))
    inbox = next(inbox for k, inbox in onshore._inboxes if k == key)
    try:
        hand_command(tool, SYSTEM, "mode", OperatorMode(7, "hold"), "the test's tool")
        assert seen.get(timeout=WAIT_S) == ("the test's tool", False)
        time.sleep(1.0)  # nothing comes again
        assert [r.message.command_id for r in inbox.drain()] == [7] and seen.empty()
        (reply,) = tool.get(key, payload=b"not a command", timeout=WAIT_S)
        assert reply.ok is None and reply.err.payload.to_bytes() and onshore.rejected[key] == 1
        assert seen.empty() and not inbox.drain()  # refused: nothing taken, nothing put out
        with pytest.raises(BusError, match="no onshore station of system 'elsewhere' took the command"):
            hand_command(tool, "elsewhere", "mode", OperatorMode(8, "hold"), "the test's tool")
    finally:
        subscriber.undeclare()
        onshore.close()
        tool.close()
        router.close()


def request(
    url: str, body: dict[str, str] | None = None, token: str = "", trust: ssl.SSLContext | None = None
) -> tuple[int, dict]:
    headers = {HEADER: token} if token else {}
    data = json.dumps(body).encode() if body is not None else None
    try:
        with urllib.request.urlopen(
            urllib.request.Request(url, data, headers), timeout=WAIT_S, context=trust
        ) as answer:
            return answer.status, json.loads(answer.read())
    except urllib.error.HTTPError as refused:
        return refused.code, json.loads(refused.read())


def base(console: Console) -> str:
    return f"http://127.0.0.1:{console.server.server_address[1]}/"


def test_a_console_bound_for_others_sends_nothing_without_the_operators_token(
    shore: tuple[zenoh.Session, zenoh.Session], caplog: pytest.LogCaptureFixture
) -> None:
    router, tool = shore
    arrived: queue.Queue[OperatorMode] = queue.Queue()

    def on_mode(sample: zenoh.Sample) -> None:
        if (mode := message_of(sample, OperatorMode)) is not None:
            arrived.put(mode)

    subscriber = tool.declare_subscriber(keys.operator_key(SYSTEM, "mode"), on_mode)
    with caplog.at_level(logging.WARNING, logger="abyss.console.server"):
        console = Console(router, SYSTEM, 0, PANEL, host="0.0.0.0")
    try:
        token = console.access.token
        assert token and f"?token={token}" in console.url and console.url.startswith("http://")
        assert "plain HTTP: its token crosses the network in the clear" in caplog.text
        hold = {"kind": "mode", "value": "hold"}
        status, body = request(base(console) + "command", hold)
        assert status == 401 and "token" in body["error"]
        assert request(base(console) + "state")[0] == 401
        assert request(base(console) + "command", hold, token="not the token")[0] == 401
        with urllib.request.urlopen(base(console), timeout=WAIT_S) as page:  # the page itself is open
            assert b"the pilot's console" in page.read()
        status, body = request(base(console) + "command", hold, token=token)
        assert status == 200
        # one session's puts arrive in order: the first to arrive is the one sent with the token
        assert arrived.get(timeout=WAIT_S).command_id == body["id"]
        status, state = request(base(console) + f"state?token={token}")
        assert status == 200 and state["commands"][0]["id"] == body["id"]
    finally:
        console.close()
        subscriber.undeclare()


def test_on_localhost_the_console_asks_nothing_and_a_tls_token_is_the_operators_own(tmp_path: Path) -> None:
    assert Access.at("127.0.0.1", SYSTEM, None).token is None
    assert Access.at("localhost", SYSTEM, None).allows("/state", {})  # type: ignore[arg-type]
    certs.make(tmp_path)
    operator = CertFiles(tmp_path, certs.OPERATOR)
    made = Access.at("0.0.0.0", SYSTEM, operator).token
    assert made == token_of(operator, SYSTEM)  # worked out again from the same key
    assert made != token_of(operator, "another system")
    assert Access.at("0.0.0.0", SYSTEM, None).token != Access.at("0.0.0.0", SYSTEM, None).token


def test_with_the_operators_certificate_the_console_is_https_that_only_the_systems_ca_vouches_for(
    shore: tuple[zenoh.Session, zenoh.Session], tmp_path: Path
) -> None:
    router, tool = shore
    certs.make(tmp_path)  # the operator's certificate names 127.0.0.1
    operator = CertFiles(tmp_path, certs.OPERATOR)
    arrived: queue.Queue[OperatorMode] = queue.Queue()  # shore took it, and puts it out as taken
    subscriber = tool.declare_subscriber(
        keys.operator_key(SYSTEM, "mode"),
        lambda sample: arrived.put(mode) if (mode := message_of(sample, OperatorMode)) else None,
    )
    console = Console(router, SYSTEM, 0, PANEL, host="0.0.0.0", certificates=operator)
    try:
        token = token_of(operator, SYSTEM)
        assert console.url.startswith("https://") and console.url.endswith(f"/?token={token}")
        at = f"127.0.0.1:{console.server.server_address[1]}/"
        trusted = ssl.create_default_context(cafile=str(operator.ca))
        with pytest.raises(urllib.error.URLError, match="CERTIFICATE_VERIFY_FAILED"):
            request(f"https://{at}state", token=token, trust=ssl.create_default_context())
        with pytest.raises((urllib.error.URLError, ConnectionError, http.client.HTTPException)):
            request(f"http://{at}state", token=token)  # plain HTTP to it gets no answer
        assert request(f"https://{at}state", trust=trusted)[0] == 401  # TLS is not the token
        status, body = request(f"https://{at}command", {"kind": "mode", "value": "hold"}, token, trusted)
        assert status == 200 and arrived.get(timeout=WAIT_S).command_id == body["id"]
    finally:
        console.close()
        subscriber.undeclare()


def test_a_second_console_sees_the_first_ones_commands_and_who_sent_them(
    shore: tuple[zenoh.Session, zenoh.Session],
) -> None:
    router, tool = shore
    first, second = Console(router, SYSTEM, 0, PANEL), Console(tool, SYSTEM, 0, PANEL)
    try:
        assert first.pilot.by != second.pilot.by
        _, sent = request(base(first) + "command", {"kind": "waypoints", "value": "5,0,-10,0; 6,1,-10,0.5"})
        shown = None
        for _ in range(int(WAIT_S / 0.05)):
            shown = next((c for c in second.pilot.state()["commands"] if c["id"] == sent["id"]), None)
            if shown is not None:
                break
            second.stop.wait(0.05)
        assert shown is not None, "the second console never saw the first one's command"
        assert shown["by"] == first.pilot.by and shown["text"] == "5,0,-10,0; 6,1,-10,0.5"
        assert shown["state"] == "sent"  # till onboard's answer reaches shore
        mine = next(c for c in first.pilot.state()["commands"] if c["id"] == sent["id"])
        assert mine["by"] == ""  # its own
        # teleop goals are counted by sender, not listed
        first.pilot.goals.start_from(telemetry())
        first.pilot.nudge("vehicle", [0.1, 0.0, 0.0], [0.0, 0.0, 0.0])
        for _ in range(int(WAIT_S / 0.05)):
            if second.pilot.state()["others_teleop"]:
                break
            second.stop.wait(0.05)
        assert second.pilot.state()["others_teleop"] == {first.pilot.by: 1}
        assert all(
            c["kind"] != "waypoints" or c["id"] == sent["id"] for c in second.pilot.state()["commands"]
        )
    finally:
        first.close()
        second.close()


def telemetry(**changed: object) -> Telemetry:
    fields: dict[str, object] = dict(
        position_m_world=np.array([1.0, 2.0, -10.0]),
        yaw_rad=0.0,
        mode="moving",
        command_id=1,
        waypoint_index=0,
        waypoints_total=2,
        position_error_m_world=np.zeros(3),
        heading_error_rad=0.0,
        arm_mode="idle",
        arm_command_id=-1,
        ee_position_error_m_world=np.zeros(3),
        ee_orientation_error_rad=0.0,
        ee_position_m_world=np.zeros(3),
        ee_orientation_wxyz_world=np.array([1.0, 0.0, 0.0, 0.0]),
        arm_positions_rad=np.zeros(4),
        failsafe="",
        failsafe_events=0,
        sim_time_s=1.0,
    )
    return Telemetry(**(fields | changed))  # type: ignore[arg-type]


def test_what_the_telemetry_says_changed_becomes_the_pilots_alerts() -> None:
    calm = telemetry()
    assert alerts_of(None, calm) == [] and alerts_of(calm, calm) == []
    assert alerts_of(calm, telemetry(failsafe="no heartbeat for 5 s")) == ["failsafe: no heartbeat for 5 s"]
    assert alerts_of(telemetry(failsafe="x"), calm) == ["failsafe left"]
    assert alerts_of(None, telemetry(failsafe="operator hold")) == ["failsafe: operator hold"]
    blocked = telemetry(arm_mode="blocked", intervention_target="valve_1")
    assert alerts_of(calm, blocked) == ["the arm blocked (intervention: valve_1)"]
    assert alerts_of(blocked, blocked) == []  # said once
    assert alerts_of(calm, telemetry(mode="missed", waypoint_index=1)) == [
        "waypoint 2 of 2 missed: its time ran out"
    ]
    failed = telemetry(intervention_id=7, intervention_target="lever_1", intervention_phase="failed",
                       intervention_reason="the grasp slipped")  # fmt: skip
    assert alerts_of(calm, failed) == ["the intervention on lever_1 failed: the grasp slipped"]
    assert alerts_of(failed, failed) == []
    assert alerts_of(calm, telemetry(boot_id=5)) == []  # a restart is shore's to tell (ShoreEvent)


def test_a_command_from_a_tool_that_gave_no_name_is_shown_as_such(
    shore: tuple[zenoh.Session, zenoh.Session],
) -> None:
    router, tool = shore
    console = Console(router, SYSTEM, 0, PANEL)
    try:
        tool.put(keys.operator_key(SYSTEM, "waypoints"), encode(Waypoints(42, np.zeros((1, 4))), 0, 0.0))
        for _ in range(int(WAIT_S / 0.05)):
            if console.pilot.state()["commands"]:
                break
            console.stop.wait(0.05)
        (shown,) = console.pilot.state()["commands"]
        assert shown["id"] == 42 and "gave no name" in shown["by"]
    finally:
        console.close()


def test_a_station_lost_and_back_is_an_alert(shore: tuple[zenoh.Session, zenoh.Session]) -> None:
    router, tool = shore
    console = Console(router, SYSTEM, 0, PANEL)
    try:

        def alerts() -> list[str]:
            return [a["text"] for a in reversed(console.pilot.state()["alerts"])]

        def until(holds: Callable[[], bool]) -> None:
            for _ in range(int(WAIT_S / 0.05)):
                if holds():
                    return
                console.stop.wait(0.05)
            raise AssertionError(f"never: alerts {alerts()}, stations {console.pilot.state()['stations']}")

        token = tool.liveliness().declare_token(keys.alive_key(SYSTEM, "vessel"))
        until(lambda: console.pilot.state()["stations"] == {"vessel": True})
        assert alerts() == []  # a station first seen is no news
        token.undeclare()
        until(lambda: alerts() == ["station vessel lost"])
        token = tool.liveliness().declare_token(keys.alive_key(SYSTEM, "vessel"))
        until(lambda: alerts() == ["station vessel lost", "station vessel back (restarted)"])
        token.undeclare()
    finally:
        console.close()


def test_what_shore_saw_of_a_restart_is_the_pilots_alert(shore: tuple[zenoh.Session, zenoh.Session]) -> None:
    """Shore tells a station's restart from the telemetry and says what it did (ShoreEvent, as the
    onshore station puts it): the console shows shore's word, and tells no restart of its own."""
    router, tool = shore
    console = Console(router, SYSTEM, 0, PANEL)
    try:
        event = ShoreEvent("onboard", "restarted: goals handed again from waypoint 2", 31.5)
        tool.put(keys.shore_event_key(SYSTEM), encode(event, 0, 0.0))
        for _ in range(int(WAIT_S / 0.05)):
            if console.pilot.state()["alerts"]:
                break
            console.stop.wait(0.05)
        assert [a["text"] for a in console.pilot.state()["alerts"]] == [
            "onboard restarted: goals handed again from waypoint 2"
        ]
    finally:
        console.close()


def test_the_onshore_station_serves_the_console_on_its_own_session_and_only_it(
    shore: tuple[zenoh.Session, zenoh.Session],
) -> None:
    router, _ = shore
    served: list[bytes] = []
    out = io.StringIO()

    def onshore(config: Config, bus: object) -> None:  # the station's run, as its shell calls it
        url = re.search(r"pilot's console at (\S+)", out.getvalue())
        assert url, out.getvalue()
        with urllib.request.urlopen(url.group(1) + "state", timeout=WAIT_S) as state:
            served.append(state.read())

    with contextlib.redirect_stdout(out):
        _with_console(onshore, 0)(Config(), types.SimpleNamespace(session=router))
    assert json.loads(served[0])["system"] == Config().system
    url = re.search(r"pilot's console at (\S+)", out.getvalue()).group(1)  # type: ignore[union-attr]
    with pytest.raises(urllib.error.URLError):  # closed with the station
        urllib.request.urlopen(url, timeout=WAIT_S)
    refused = subprocess.run(
        [sys.executable, "-m", "abyss.cli", "station", "vessel", "--console", "0"],
        capture_output=True,
        text=True,
    )
    assert (
        refused.returncode != 0
        and "served by the onshore station, not vessel" in refused.stderr + refused.stdout
    )


def test_an_address_the_console_cannot_serve_on_is_refused_by_name(
    shore: tuple[zenoh.Session, zenoh.Session],
) -> None:
    router, _ = shore
    with pytest.raises(
        ConfigError, match=r"cannot serve on nonsense\.invalid:0 \(--console, or --bind and --port\)"
    ):
        Console(router, SYSTEM, 0, PANEL, host="nonsense.invalid")


@pytest.mark.parametrize("asked", [signal.SIGINT, signal.SIGTERM])
def test_abyss_console_serves_until_asked_to_stop_then_closes_and_exits_at_once(
    asked: signal.Signals,
) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = open_session(zenoh_config([endpoint], mode="router"), "the test's shore")
    payload = description_payload(SYSTEM, robot_at(""), site_at(""))
    served = description.serve(router, SYSTEM, "onshore", payload)  # as a station's shell does
    console = subprocess.Popen(
        [sys.executable, "-P", "-m", "abyss.cli", "console", "--connect", endpoint, "--system", SYSTEM],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert console.stdout is not None
        url = re.search(r"abyss console: (http://\S+)", console.stdout.readline())
        assert url, console.communicate(timeout=WAIT_S)
        with urllib.request.urlopen(url.group(1) + "state", timeout=WAIT_S) as state:
            assert json.loads(state.read())["system"] == SYSTEM
        console.send_signal(asked)
        _, err = console.communicate(timeout=WAIT_S)  # closed within its bound (common.leave)
        assert console.returncode == 0 and "not stopped" not in err, err
        with pytest.raises(urllib.error.URLError):
            urllib.request.urlopen(url.group(1), timeout=WAIT_S)
    finally:
        if console.poll() is None:
            console.kill()
        served.undeclare()
        router.close()
