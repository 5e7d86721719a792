"""Where this host sends a neighbour's packets: the kernel's own route, as `ip route get` says."""

from __future__ import annotations

import json
import socket
import subprocess
import time
from dataclasses import dataclass

from abyss.common.errors import LinkError


@dataclass(frozen=True)
class Route:
    address: str  # the neighbour's IPv4 address
    device: str  # the interface the kernel sends it through
    source: str  # this host's address on that route


def route_towards(host: str, timeout_s: float = 30.0) -> Route:
    """The route this host takes to `host` (a name or an address). A name is retried for
    `timeout_s` (a neighbour's container may start later)."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            address = str(socket.getaddrinfo(host, None, socket.AF_INET)[0][4][0])
            break
        except socket.gaierror as exc:
            if time.monotonic() > deadline:
                raise LinkError(
                    f"cannot resolve the neighbour {host!r} ({exc}); give its address "
                    "with --peer (an IPv4 address)"
                ) from None
            time.sleep(0.5)
    done = subprocess.run(["ip", "-j", "route", "get", address], capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise LinkError(f"no route to the neighbour {host} ({address}): {done.stderr.strip()}")
    route = json.loads(done.stdout)[0]
    if route["dev"] == "lo":
        raise LinkError(
            f"the neighbour {host} ({address}) is on this host: shaping lo would shape every "
            "local connection; run the stations on separate hosts, containers or network "
            "namespaces (abyss lab), or use --link emulated"
        )
    return Route(address, str(route["dev"]), str(route.get("prefsrc", "")))
