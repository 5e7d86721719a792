"""Separate hosts on one machine: `abyss lab`'s topology (abyss.launch.lab), one network namespace
per station joined along the hops only, with the helpers the namespace tests use on it."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import uuid
from pathlib import Path

from abyss.interface import keys
from abyss.launch.lab import PORT, Lab, usable

ROOT = Path(__file__).resolve().parents[2]
__all__ = ["PORT", "ROOT", "Hosts", "usable"]


class Hosts(Lab):
    """A lab of its own for one test; `ends`: each (station, hop) with an interface."""

    def __init__(self) -> None:
        super().__init__(f"t{uuid.uuid4().hex[:6]}")
        self.ends = [(station, hop) for hop, stations in keys.HOPS.items() for station in stations]

    def popen(self, station: str, args: list[str], log_path: Path) -> subprocess.Popen[bytes]:
        with log_path.open("wb") as log:
            return subprocess.Popen(
                [*self.prefix(station), sys.executable, *args],
                cwd=ROOT,
                stdout=log,
                stderr=subprocess.STDOUT,
                stdin=subprocess.DEVNULL,
            )

    def run(
        self, station: str, args: list[str], timeout_s: float, env: dict[str, str] | None = None
    ) -> subprocess.CompletedProcess[str]:
        """`python ARGS` on the station's host, with `env` added to this process's environment."""
        return subprocess.run(
            [*self.prefix(station), sys.executable, *args],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=timeout_s,
            check=False,
            env={**os.environ, **(env or {})},
        )

    def bytes_sent(self, station: str, hop: str) -> int:
        """Bytes the station's interface on `hop` has sent."""
        done = subprocess.run(
            ["ip", "-n", self.netns(station), "-s", "-j", "link", "show", self.device(station, hop)],
            capture_output=True,
            text=True,
            check=True,
        )
        return int(json.loads(done.stdout)[0]["stats64"]["tx"]["bytes"])

    def reaches(self, station: str, address: str) -> bool:
        """Whether the station's host has a route to `address`."""
        done = subprocess.run(
            ["ip", "-n", self.netns(station), "route", "get", address],
            capture_output=True,
            text=True,
            check=False,
        )
        return done.returncode == 0
