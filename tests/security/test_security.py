"""Access control generated from the key table, and Zenoh's log read back into refusals."""

from __future__ import annotations

import io
import logging
from pathlib import Path

import pytest

from abyss.common.errors import ConfigError
from abyss.interface import keys
from abyss.security import certs
from abyss.security.access import RefusalLog, access_control, check_endpoints

# Zenoh 1.10's own lines (colours stripped), as a station's stdout shows them
DENIED = (
    "2026-11-22T10:44:06Z TRACE rx-0 ThreadId(10) zenoh::net::routing::interceptor::access_control: "
    "c239 on Interface(rov1)+CertCommonName(simulation)+Transport(Tls)+c239 is unauthorized to "
    "Put (ingress) on abyss/s/vessel/goal/waypoints"
)
DROPPED = "2026-11-22T10:44:06Z TRACE rx-0 ThreadId(10) zenoh::net::routing::interceptor: Msg intercepted!"
ALLOWED = DENIED.replace("is unauthorized", "is authorized")
HANDSHAKE = (
    "2026-11-22T10:44:39Z  WARN acc-0 ThreadId(06) zenoh_link_tls::unicast: "
    "peer sent no certificates. Hint: increase the system open file limit."
)
OTHER = (
    "2026-11-22T10:44:39Z  WARN net-0 ThreadId(03) zenoh::net::runtime::orchestrator: Scouting delay elapsed"
)


def rules_for(station: str, holder: str) -> list[dict[str, object]]:
    acl = access_control(station)
    policy = next(p for p in acl["policies"] if p["subjects"] == [holder])
    return [r for r in acl["rules"] if r["id"] in policy["rules"]]


@pytest.mark.parametrize("station", keys.STATIONS)
def test_each_received_key_is_taken_only_from_its_publisher(station: str) -> None:
    for spec in (s for s in keys.KEYS if s.to == station):
        key = f"abyss/*/{spec.station}/{spec.topic}"
        for holder in certs.HOLDERS:
            denied = any(
                r["permission"] == "deny" and key in r["key_exprs"] and "put" in r["messages"]
                for r in rules_for(station, holder)
            )
            assert denied == (holder != spec.station), (station, key, holder)
    assert access_control(station)["default_permission"] == "deny"  # an unknown holder gets nothing


def test_a_denial_counts_once_the_message_is_dropped(caplog: pytest.LogCaptureFixture) -> None:
    out = io.StringIO()
    refusals = RefusalLog(out)
    with caplog.at_level(logging.WARNING):
        for line in (DENIED, ALLOWED, DENIED, DROPPED, DENIED, DROPPED, HANDSHAKE, OTHER):
            refusals.take(line + "\n")
    what = "simulation: put on abyss/s/vessel/goal/waypoints (ingress)"
    # the first denial was Zenoh filling its permission cache: nothing was dropped then
    assert refusals.refused == {what: 2, "TLS handshake: peer sent no certificates": 1}
    assert caplog.text.count(f"access control denied: {what}") == 1  # logged once, counted twice
    assert "peer refused: TLS handshake: peer sent no certificates" in caplog.text
    assert out.getvalue() == OTHER + "\n"  # the rest of Zenoh's log is passed on


def test_endpoints_and_certificates_agree(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="needs certificates"):
        check_endpoints(["tls/127.0.0.1:7447"], None)
    files = certs.CertFiles(tmp_path, "vessel")
    with pytest.raises(ConfigError, match="every endpoint must be tls"):
        check_endpoints(["tcp/127.0.0.1:7447"], files)
    with pytest.raises(ConfigError, match="abyss certs make"):
        files.check()
    certs.make(tmp_path)
    assert files.check() is files


def test_bad_deployment_arguments_name_the_field(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from abyss.cli import main

    assert main(["certs", "make", str(tmp_path), "--host", "mallory=10.0.0.9"]) == 2
    assert (
        "--host: unknown holder 'mallory'; allowed: simulation, onboard, vessel, onshore, operator"
        in capsys.readouterr().err
    )
    assert main(["station", "vessel", "--peer", "sea=10.0.0.9"]) == 2
    assert "hop: unknown hop 'sea'; allowed: rov, tether, satellite" in capsys.readouterr().err
    assert main(["station", "vessel", "--peer", "tether"]) == 2
    assert "--peer: 'tether' is not KEY=VALUE" in capsys.readouterr().err
    assert main(["station", "vessel", "--tls", str(tmp_path / "none"), "--listen", "tls/127.0.0.1:0"]) == 2
    assert "abyss certs make" in capsys.readouterr().err
    assert main(["certs", "make", str(tmp_path), "--host", "vessel=10.0.0.9"]) == 0
    assert (tmp_path / "vessel.pem").is_file() and (tmp_path / "operator.key").stat().st_mode & 0o077 == 0
