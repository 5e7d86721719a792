"""Separate hosts on one machine: one network namespace per station, joined by veth pairs as
compose.yaml's networks join the containers (rov: simulation-onboard, tether: onboard-vessel,
satellite: vessel-onshore), so that nothing can pass between two stations but along a hop."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import uuid
from dataclasses import dataclass, field
from pathlib import Path

from abyss.common import keys

ROOT = Path(__file__).resolve().parents[2]
PORT = 7447
SUBNET = "10.231.{index}.{host}"  # one /24 per hop, only inside the namespaces made here


def usable() -> str:
    """Why namespaces cannot be made here ('' when they can)."""
    if os.geteuid() != 0:
        return "needs root to make network namespaces"
    if shutil.which("ip") is None:
        return "needs iproute2"
    return ""


def ip(*args: str, netns: str | None = None) -> str:
    command = ["ip", *(["-n", netns] if netns else []), *args]
    return subprocess.run(command, capture_output=True, text=True, check=True).stdout


@dataclass
class Hosts:
    """The four namespaces; `address[(station, hop)]` is a station's address on a hop."""

    tag: str = field(default_factory=lambda: uuid.uuid4().hex[:6])
    address: dict[tuple[str, str], str] = field(default_factory=dict)
    device: dict[tuple[str, str], str] = field(default_factory=dict)

    def netns(self, station: str) -> str:
        return f"abyss-{self.tag}-{station}"

    def make(self) -> Hosts:
        for station in keys.STATIONS:
            subprocess.run(["ip", "netns", "add", self.netns(station)], check=True)
            ip("link", "set", "lo", "up", netns=self.netns(station))
        for index, (hop, ends) in enumerate(keys.HOPS.items(), start=1):
            for end, station in enumerate(ends):
                self.device[(station, hop)] = f"{hop}{end}"
                self.address[(station, hop)] = SUBNET.format(index=index, host=end + 1)
            a, b = ends
            ip("link", "add", f"{hop}0", "netns", self.netns(a), "type", "veth",
               "peer", "name", f"{hop}1", "netns", self.netns(b))
            for station in ends:
                ns, dev = self.netns(station), self.device[(station, hop)]
                ip("addr", "add", f"{self.address[(station, hop)]}/24", "dev", dev, netns=ns)
                ip("link", "set", dev, "up", netns=ns)
        return self

    def remove(self) -> None:
        for station in keys.STATIONS:
            subprocess.run(["ip", "netns", "del", self.netns(station)], capture_output=True, check=False)

    def endpoints(self, station: str, scheme: str) -> list[str]:
        """`abyss station` options: listen on each hop's address (and loopback, for tools on that
        host); connect towards the vehicle (onboard to simulation, vessel to onboard, ...)."""
        args = ["--listen", f"{scheme}/127.0.0.1:{PORT}"]
        for hop, neighbour in keys.hops_of(station).items():
            args += ["--listen", f"{scheme}/{self.address[(station, hop)]}:{PORT}"]
            if keys.STATIONS.index(neighbour) < keys.STATIONS.index(station):
                args += ["--connect", f"{scheme}/{self.address[(neighbour, hop)]}:{PORT}"]
            args += ["--peer", f"{hop}={self.address[(neighbour, hop)]}"]
        return args

    def popen(self, station: str, args: list[str], log_path: Path) -> subprocess.Popen[bytes]:
        with log_path.open("wb") as log:
            return subprocess.Popen(["ip", "netns", "exec", self.netns(station), sys.executable, *args],
                                    cwd=ROOT, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)

    def run(self, station: str, args: list[str], timeout_s: float,
            env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
        """`python ARGS` on the station's host, with `env` added to this process's environment."""
        return subprocess.run(["ip", "netns", "exec", self.netns(station), sys.executable, *args],
                              cwd=ROOT, capture_output=True, text=True, timeout=timeout_s, check=False,
                              env={**os.environ, **(env or {})})

    def bytes_sent(self, station: str, hop: str) -> int:
        """Bytes the station's interface on `hop` has sent."""
        device = self.device[(station, hop)]
        info = json.loads(ip("-s", "-j", "link", "show", device, netns=self.netns(station)))
        return int(info[0]["stats64"]["tx"]["bytes"])

    def reaches(self, station: str, address: str) -> bool:
        """Whether the station's host has a route to `address`."""
        done = subprocess.run(["ip", "-n", self.netns(station), "route", "get", address],
                              capture_output=True, text=True, check=False)
        return done.returncode == 0
