"""The running system's description (interface.system_description, bus.description): what a station
serves reads back as the packages it was made from; a malformed one is refused with its reason; and
the operator's tools check their commands against the system that is running, not the shipped
packages (a system on the small panel, whose parts are `valve` and `lever`, refuses `valve_1`)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh

from abyss.bus import description
from abyss.bus.session import open_session, zenoh_config
from abyss.common.errors import BadInput, BusError
from abyss.common.ports import free_port
from abyss.description.robot import robot_at
from abyss.description.site import site_at
from abyss.interface import faults
from abyss.interface.system_description import description_of, description_payload

SYSTEM = "description-test"
SMALL = description_payload(SYSTEM, robot_at("bluerov2_heavy_alpha5"), site_at("small_panel"))


@pytest.mark.parametrize(("robot", "site"), [("", ""), ("bluerov2_heavy_alpha5", "small_panel")])
def test_a_description_reads_back_as_its_packages(robot: str, site: str) -> None:
    served = description_of(description_payload(SYSTEM, robot_at(robot), site_at(site)))
    assert served.system == SYSTEM
    assert served.robot == robot_at(robot).spec and served.site == site_at(site).spec
    assert served.model_names == faults.model_names(robot_at(robot).spec, site_at(site).panel)


def test_a_malformed_description_is_refused_with_its_reason() -> None:
    table = json.loads(SMALL)
    for payload, reason in (
        (b"\xff not json", "a malformed description"),
        (json.dumps({"system": SYSTEM, "robot": table["robot"]}).encode(), "system, robot and site"),
        (json.dumps({**table, "robot": {**table["robot"], "thrusters": 3}}).encode(), "thrusters"),
    ):
        with pytest.raises(BadInput, match=reason):
            description_of(payload)


@pytest.fixture
def router() -> Iterator[tuple[zenoh.Session, str]]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    session = open_session(zenoh_config([endpoint]), "test station")
    yield session, endpoint
    session.close()


def _tool(endpoint: str) -> zenoh.Session:
    return open_session(zenoh_config(connect=[endpoint], mode="client"), "test tool")


def test_a_tool_fetches_what_a_station_serves_and_is_told_when_none_does(
    router: tuple[zenoh.Session, str],
) -> None:
    session, endpoint = router
    tool = _tool(endpoint)
    try:
        with pytest.raises(BusError, match=f"no station of system '{SYSTEM}' described"):
            description.fetch(tool, SYSTEM, timeout_s=1.0)
        served = description.serve(session, SYSTEM, "vessel", SMALL)
        assert description.fetch(tool, SYSTEM).panel == site_at("small_panel").panel
        with pytest.raises(BusError, match="no station of system 'another'"):
            description.fetch(tool, "another", timeout_s=1.0)  # another system's is not this one's
        served.undeclare()
        bad = description.serve(session, SYSTEM, "onshore", b"{}")
        with pytest.raises(BadInput, match="described itself wrongly: a description is a JSON object"):
            description.fetch(tool, SYSTEM, timeout_s=1.0)
        bad.undeclare()
    finally:
        tool.close()


def test_the_operators_tools_check_against_the_running_site(router: tuple[zenoh.Session, str]) -> None:
    """`abyss op` and `abyss fault`, as real processes, on a system that runs the small panel: a
    part of the shipped panel is none of its parts, and each says which are."""
    session, endpoint = router
    served = description.serve(session, SYSTEM, "onshore", SMALL)
    env = {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "HOME": os.environ.get("HOME", "/root")}
    link = ["--connect", endpoint, "--system", SYSTEM]
    try:
        for words, said in (
            (["op", "valve", "valve_1", "--turn", "90"], "'valve_1' is not a part of the panel"),
            (["op", "lever", "valve", "--to", "up"], "valve is a valve, not a lever"),
            (["fault", "seize", "valve_1", "1"], "seize target 'valve_1' not one of valve, lever"),
        ):
            done = subprocess.run(
                [sys.executable, "-P", "-m", "abyss.cli", *words, *link],
                capture_output=True,
                text=True,
                env=env,
                cwd=Path(__file__).parent,
                timeout=120,
            )
            assert done.returncode != 0 and said in done.stdout + done.stderr, (
                words,
                done.stdout + done.stderr,
            )
    finally:
        served.undeclare()
