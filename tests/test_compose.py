"""compose.yaml: valid for Compose, and in agreement with the code (stations, hops, profiles,
ports, the station command line) with its defaults and with the environment's overrides."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import tomllib
from pathlib import Path
from typing import Any

import pytest
import yaml

from abyss.cli import parser
from abyss.config.linkprofile import load_profiles
from abyss.config.system import LinksConfig
from abyss.interface import keys
from abyss.launch.start import DEFAULT_PORT

ROOT = Path(__file__).resolve().parents[1]
OVERRIDES = {
    "ABYSS_TLS": "tls",
    "ABYSS_TLS_DIR": "/certs",
    "ABYSS_SATELLITE_PROFILE": "satellite-storm",
    "ABYSS_TETHER_PROFILE": "tether-degraded",
    "ABYSS_SYSTEM": "field",
    "ABYSS_LINK": "emulated",
    "ABYSS_ONBOARD_CPUS": "0.3",
}


def resolved(env: dict[str, str]) -> dict[str, Any]:
    """compose.yaml as Compose reads it: validated against its schema, variables substituted."""
    if shutil.which("docker-compose") is None:
        pytest.skip("docker-compose not installed (setup.sh installs it as root)")
    clean = {k: v for k, v in os.environ.items() if not k.startswith("ABYSS_")}
    done = subprocess.run(
        ["docker-compose", "-f", str(ROOT / "compose.yaml"), "config"],
        cwd=ROOT,
        env={**clean, **env},
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    return yaml.safe_load(done.stdout)  # type: ignore[no-any-return]


def option_values(command: list[str], option: str) -> list[str]:
    return [command[i + 1] for i, word in enumerate(command) if word == option]


@pytest.mark.parametrize("env", [{}, OVERRIDES], ids=["defaults", "overrides"])
def test_compose_agrees_with_the_code(env: dict[str, str]) -> None:
    compose = resolved(env)
    assert set(compose["services"]) == set(keys.STATIONS)
    assert set(compose["networks"]) == set(keys.HOPS)
    links = LinksConfig()
    for station, service in compose["services"].items():
        hops = keys.hops_of(station)
        assert set(service["networks"]) == set(hops), station  # only the networks of its hops
        command = service["command"]
        args = parser().parse_args(command)  # the station's own command line accepts it
        assert args.func.__name__ == "cmd_station" and args.name == station
        assert args.system == env.get("ABYSS_SYSTEM", "compose")
        assert args.link == env.get("ABYSS_LINK", "auto")  # netem, else the TUN shaper, else emulated
        assert "NET_ADMIN" in service["cap_add"]  # tc/netem or a TUN device on its own interfaces
        cpus = float(env.get(f"ABYSS_{station.upper()}_CPUS", 0))
        assert float(service.get("cpus", 0)) == cpus, station  # --cpu's cap, or none
        assert "/dev/net/tun" in str(service["devices"])  # the TUN shaper's device
        scheme = env.get("ABYSS_TLS", "tcp")
        assert args.listen == [f"{scheme}/0.0.0.0:{DEFAULT_PORT}"]
        # connects towards the vehicle, to the neighbour's service name on their shared network
        towards = [n for n in hops.values() if keys.STATIONS.index(n) < keys.STATIONS.index(station)]
        assert args.connect == [f"{scheme}/{n}:{DEFAULT_PORT}" for n in towards]
        profiles = dict(item.split("=", 1) for item in args.profile)
        assert set(profiles) == set(hops), station
        for hop, name in profiles.items():
            variable = f"ABYSS_{hop.upper()}_PROFILE"
            assert name == env.get(variable, getattr(links, hop)), (station, hop)
            assert name in load_profiles()
        health = service["healthcheck"]["test"]
        assert health[:2] == ["CMD", "abyss"]
        health_args = parser().parse_args(health[2:])
        assert health_args.func.__name__ == "cmd_health" and health_args.station == station
        assert health_args.connect == f"{scheme}/127.0.0.1:{DEFAULT_PORT}"
        assert service["environment"]["ABYSS_TLS_DIR"] == env.get("ABYSS_TLS_DIR", "")
    onshore = compose["services"]["onshore"]
    assert "onshore.record_dir=/runs" in option_values(onshore["command"], "--set")
    for station in keys.STATIONS:  # every station's bus recording in the shared volume
        service = compose["services"][station]
        assert "record.directory=/runs/record" in option_values(service["command"], "--set"), station
        assert "runs:/runs:rw" in service["volumes"], station
    assert "runs:/runs:rw" in onshore["volumes"]  # the recording outlives the container
    assert str(DEFAULT_PORT) in str(onshore["ports"])


def test_the_image_installs_what_setup_installs() -> None:
    dockerfile = (ROOT / "Dockerfile").read_text()
    assert "apt-packages.txt" in dockerfile and "apt-packages.txt" in (ROOT / "setup.sh").read_text()
    # the official image by default, any Debian 12 with Python 3.11 instead (deploy/base-image.sh)
    assert "ARG BASE=python:3.11-slim-bookworm" in dockerfile and "FROM ${BASE}" in dockerfile
    assert "python3 -m venv /opt/abyss" in dockerfile and "ENV PATH=/opt/abyss/bin:$PATH" in dockerfile
    assert 'ENTRYPOINT ["abyss"]' in dockerfile
    # every package folder goes into the image (pip refuses a package list with one missing)
    packages = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]
    folders = {name.split(".")[1] for name in packages if name.count(".") >= 1}
    copied = set(re.findall(r"^COPY (\w+) \1$", dockerfile, re.MULTILINE))
    assert folders <= copied, sorted(folders - copied)


def test_an_invalid_compose_file_is_refused(tmp_path: Path) -> None:
    """The validation can fail: a misspelt service field is refused, naming it."""
    if shutil.which("docker-compose") is None:
        pytest.skip("docker-compose not installed (setup.sh installs it as root)")
    broken = yaml.safe_load((ROOT / "compose.yaml").read_text())
    broken["services"]["vessel"]["netwroks"] = broken["services"]["vessel"].pop("networks")
    (tmp_path / "compose.yaml").write_text(yaml.safe_dump(broken))
    done = subprocess.run(
        ["docker-compose", "-f", str(tmp_path / "compose.yaml"), "config", "-q"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode != 0 and "netwroks" in done.stderr
