"""`abyss lab`: the whole system on one Linux machine as four network namespaces, one per
station, joined by veth pairs along the hops only (rov: simulation-onboard, tether:
onboard-vessel, satellite: vessel-onshore), as compose.yaml's networks join the containers.
Each station shapes its own packets towards its neighbours (`--link auto`: netem where the
kernel has it, else the TUN shaper), so real Zenoh over real kernel TCP crosses each hop's
profile. `abyss up` supervises from shore's namespace.

A lab's namespaces are `abyss-<name>-<station>`; its record in /run/abyss-lab/<name>.json names
the process that owns it, so a lab left by a killed run is told from one in use and removed."""

from __future__ import annotations

import ctypes
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from abyss.common.errors import ConfigError, LinkError
from abyss.interface import keys

PORT = 7447  # each station listens here on its hop addresses and on its loopback
SUBNET = "10.231.{index}.{host}"  # one /24 per hop; only inside the lab's namespaces
RECORDS = Path("/run/abyss-lab")
NAME_PATTERN = re.compile(r"[a-z0-9][a-z0-9-]{0,15}")
CLONE_NEWNET = 0x40000000


def usable() -> str:
    """Why a lab cannot be made here ('' when it can)."""
    if os.geteuid() != 0:
        return "a lab makes network namespaces: run it as root (sudo abyss lab ...)"
    if shutil.which("ip") is None:
        return "a lab needs iproute2 (apt-get install iproute2)"
    return ""


def ip(*args: str, netns: str | None = None) -> str:
    command = ["ip", *(["-n", netns] if netns else []), *args]
    done = subprocess.run(command, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise LinkError(f"`{' '.join(command)}` failed: {done.stderr.strip()}")
    return done.stdout


def owner_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


@dataclass
class Lab:
    """The four namespaces of lab `name`; `address(station, hop)` is a station's address on a hop
    and `device(station, hop)` its interface there."""

    name: str = "lab"

    def __post_init__(self) -> None:
        if not NAME_PATTERN.fullmatch(self.name):
            raise ConfigError(
                "--name",
                f"{self.name!r}: lower-case letters, digits and '-', at most 16, "
                "starting with a letter or digit",
            )

    def netns(self, station: str) -> str:
        return f"abyss-{self.name}-{keys.check_station(station)}"

    @property
    def record(self) -> Path:
        return RECORDS / f"{self.name}.json"

    @staticmethod
    def address(station: str, hop: str) -> str:
        index = list(keys.HOPS).index(hop) + 1
        return SUBNET.format(index=index, host=keys.HOPS[hop].index(station) + 1)

    @staticmethod
    def device(station: str, hop: str) -> str:
        return f"{hop}{keys.HOPS[hop].index(station)}"

    def existing(self) -> list[str]:
        """This lab's namespaces that exist now."""
        names = {line.split()[0] for line in ip("netns", "list").splitlines() if line.strip()}
        return [self.netns(s) for s in keys.STATIONS if self.netns(s) in names]

    def owner(self) -> int | None:
        """The live process that owns the lab, if any."""
        try:
            pid = int(json.loads(self.record.read_text())["pid"])
        except (OSError, ValueError, KeyError, TypeError):
            return None
        return pid if pid != os.getpid() and owner_alive(pid) else None

    def make(self, echo: object = print) -> Lab:
        """Make the namespaces and the hops; a lab left by a killed run is removed first. Nothing
        is left behind when a step fails."""
        if reason := usable():
            raise LinkError(reason)
        if self.existing():
            self.check_ours()
            pid = self.owner()
            if pid is not None:
                raise LinkError(
                    f"lab {self.name!r} is in use by process {pid}: stop it (`abyss lab down "
                    f"--name {self.name}`) or give this one another --name"
                )
            self.remove()
            if callable(echo):
                echo(f"abyss: removed lab {self.name!r} left by a run that was killed")
        RECORDS.mkdir(parents=True, exist_ok=True)
        self.record.write_text(
            json.dumps({"pid": os.getpid(), "namespaces": [self.netns(s) for s in keys.STATIONS]})
        )
        try:
            for station in keys.STATIONS:
                ip("netns", "add", self.netns(station))
                ip("link", "set", "lo", "up", netns=self.netns(station))
            for hop, (a, b) in keys.HOPS.items():
                ip(
                    "link",
                    "add",
                    self.device(a, hop),
                    "netns",
                    self.netns(a),
                    "type",
                    "veth",
                    "peer",
                    "name",
                    self.device(b, hop),
                    "netns",
                    self.netns(b),
                )
                for station in (a, b):
                    ns, dev = self.netns(station), self.device(station, hop)
                    ip("addr", "add", f"{self.address(station, hop)}/24", "dev", dev, netns=ns)
                    ip("link", "set", dev, "up", netns=ns)
        except LinkError:
            self.remove()
            raise
        return self

    def remove(self) -> None:
        for station in keys.STATIONS:
            subprocess.run(["ip", "netns", "del", self.netns(station)], capture_output=True, check=False)
        self.record.unlink(missing_ok=True)

    def check_ours(self) -> None:
        """LinkError when a namespace of this lab's name exists that no lab made (no record):
        someone else's, never removed here."""
        if (found := self.existing()) and not self.record.is_file():
            raise LinkError(
                f"network namespace {found[0]} exists and is no abyss lab's (no "
                f"{self.record}): give this lab another --name, or remove it "
                f"(`ip netns del {found[0]}`) if it is yours"
            )

    def down(self, timeout_s: float = 15.0) -> str:
        """Stop the run that owns the lab (SIGTERM, as Ctrl-C) and remove the lab; what was done."""
        self.check_ours()
        pid = self.owner()
        if pid is not None:
            os.kill(pid, signal.SIGTERM)
            deadline = time.monotonic() + timeout_s
            while owner_alive(pid) and time.monotonic() < deadline:
                time.sleep(0.1)
        found = self.existing()
        self.remove()
        if pid is None and not found:
            return f"no lab {self.name!r} here"
        return f"lab {self.name!r} removed" + (f" (its run, process {pid}, was stopped)" if pid else "")

    def prefix(self, station: str) -> list[str]:
        """What runs a command on the station's host."""
        return ["ip", "netns", "exec", self.netns(station)]

    def shape(self, station: str, hop: str, profile: str, *options: str) -> list[str]:
        """`abyss link shape` on the station's host: its packets across `hop`, towards the
        neighbour there, shaped with `profile` (and `options`: fields, --seed, --every ...)."""
        neighbour = next(s for s in keys.HOPS[hop] if s != station)
        return [
            *self.prefix(station),
            sys.executable,
            "-P",
            "-m",
            "abyss.cli",
            "link",
            "shape",
            hop,
            "--peer",
            self.address(neighbour, hop),
            "--profile",
            profile,
            *options,
        ]

    def endpoints(self, station: str, scheme: str = "tcp", loopback: bool = True) -> list[str]:
        """`abyss station` options: listen on each hop's address (and loopback, for tools on that
        host); connect towards the vehicle (onboard to simulation, vessel to onboard, ...); each
        hop's neighbour by address for the shaper."""
        args = ["--listen", f"{scheme}/127.0.0.1:{PORT}"] if loopback else []
        for hop, neighbour in keys.hops_of(station).items():
            args += ["--listen", f"{scheme}/{self.address(station, hop)}:{PORT}"]
            if keys.STATIONS.index(neighbour) < keys.STATIONS.index(station):
                args += ["--connect", f"{scheme}/{self.address(neighbour, hop)}:{PORT}"]
            args += ["--peer", f"{hop}={self.address(neighbour, hop)}"]
        return args

    def enter(self, station: str) -> None:
        """Move this process into the station's namespace. Only while it has one thread: a thread
        started before keeps the namespace it had."""
        with open(f"/run/netns/{self.netns(station)}", "rb") as handle:
            if ctypes.CDLL(None, use_errno=True).setns(handle.fileno(), CLONE_NEWNET) != 0:
                raise LinkError(f"cannot enter {self.netns(station)}: {os.strerror(ctypes.get_errno())}")


@dataclass
class LabPlacement:
    """`abyss up`'s stations in the lab: each in its namespace, listening on its hop addresses,
    shaping its own egress (`link`); the supervisor, in shore's namespace, reached by shore."""

    lab: Lab
    link: str = "auto"

    def prefix(self, station: str) -> list[str]:
        return self.lab.prefix(station)

    def args(self, station: str, endpoint: str) -> list[str]:
        supervisor = ["--connect", endpoint] if station == "onshore" else []
        return [*self.lab.endpoints(station), *supervisor, "--link", self.link]

    def shape_for(self, station: str, profiles: dict[str, str]) -> list[list[str]]:
        """Commands that shape an external station's egress (your component hosts no shaper):
        `abyss link shape` on its host, one per hop."""
        return [self.lab.shape(station, hop, profiles[hop], "--every", "60") for hop in keys.hops_of(station)]
