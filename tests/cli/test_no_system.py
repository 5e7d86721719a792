"""A tool that talks to a running system (abyss link, fault, op, health) with no system at its
endpoint says so, once prefixed: not Zenoh's failure to open a session, nor a listen endpoint."""

from __future__ import annotations

import pytest

from abyss.cli import main
from abyss.common.ports import free_port

COMMANDS = (
    ["link", "set", "satellite", "--loss", "10%"],
    ["link", "show"],
    ["fault", "clear"],
    ["op", "valve", "valve_1", "--turn", "90"],
    ["health", "onboard"],
)


@pytest.mark.parametrize("command", COMMANDS, ids=lambda c: " ".join(c[:2]))
def test_no_system_running_is_said_so(command: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    assert main([*command, "--connect", endpoint, "--system", "mine"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(
        f"abyss: no system is running at {endpoint} (system mine): start one with `abyss up`"
    )
    assert "abyss: abyss" not in err and "Zenoh session" not in err and "listen" not in err, err
