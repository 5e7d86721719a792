"""The TUN shaper: kernel TCP through linkemu's own stages, without netem.

This host's packets towards a neighbour are routed into a TUN device; a forwarder reads
them, runs each through the hop's stages (duplicate, serialise with a tail-drop queue, loss,
corrupt, delay: the same `Pipeline` the in-process link uses) and, at the time the emulated
wire delivers it, writes it on through the real interface with a raw IP socket bound to that
interface (so the kernel does not route it back into the TUN). It shapes this host's egress,
as netem on the interface would; the neighbour's shaper does the other direction. The
transport is the real one: the kernel's TCP retransmits, acknowledges and backs off.

As mahimahi's link shells, but on the route, not the namespace: it works the same between
network namespaces, containers and separate hosts. Corruption flips a bit after the IP header
(the raw socket rewrites that header's checksum; the TCP/UDP/ICMP checksum catches the flip,
as it catches netem's). What the forwarder drops is counted by reason; packets the kernel
dropped because the forwarder did not read in time are the TUN device's `tx_dropped`.
"""

from __future__ import annotations

import errno
import fcntl
import heapq
import itertools
import logging
import os
import select
import socket
import struct
import subprocess
import threading
import time
from pathlib import Path

import numpy as np

from abyss.common.errors import LinkError
from abyss.common.samples import Samples
from abyss.config.linkprofile import LinkProfile
from abyss.linkemu.link import Pipeline
from abyss.linkemu.route import Route
from abyss.linkemu.stages import Packet

log = logging.getLogger(__name__)
TUN_PATH = "/dev/net/tun"
TUNSETIFF = 0x400454CA
IFF_TUN, IFF_NO_PI = 0x0001, 0x1000
IFNAMSIZ = 16
COUNTERS = (
    "packets_sent",
    "bytes_sent",
    "packets_forwarded",
    "bytes_forwarded",
    "queue_drops",
    "losses",
    "outages",
    "packets_corrupted",
    "duplicates",
    "not_ipv4",
    "send_errors",
)


def tun_name(hop: str) -> str:
    """The TUN device of a hop's egress (Linux names hold 15 characters)."""
    return f"abyss-{hop}"[: IFNAMSIZ - 1]


def open_tun(name: str) -> int:
    """A new TUN device `name` (IP packets, no header); it goes away when the file is closed."""
    try:
        fd = os.open(TUN_PATH, os.O_RDWR | os.O_CLOEXEC)
    except FileNotFoundError:
        raise LinkError(
            f"no {TUN_PATH}: load the tun module (`modprobe tun`); in a container, give "
            "it the device (compose: `devices: [/dev/net/tun]`, docker run: "
            "`--device /dev/net/tun`)"
        ) from None
    except PermissionError:
        raise LinkError(
            f"{TUN_PATH} is not accessible: run as root or with CAP_NET_ADMIN "
            "(compose: `cap_add: [NET_ADMIN]`)"
        ) from None
    try:
        fcntl.ioctl(fd, TUNSETIFF, struct.pack(f"{IFNAMSIZ}sH22x", name.encode(), IFF_TUN | IFF_NO_PI))
    except OSError as exc:
        os.close(fd)
        if exc.errno == errno.EPERM:
            raise LinkError(
                f"making TUN device {name} needs CAP_NET_ADMIN: run as root, or give the "
                "container `cap_add: [NET_ADMIN]`"
            ) from None
        if exc.errno == errno.EBUSY:
            raise LinkError(
                f"a TUN device named {name} is in use by another process on this host: stop "
                "it (one shaper per hop and host) or run this one in its own namespace"
            ) from None
        raise LinkError(f"cannot make TUN device {name}: {exc}") from None
    return fd


def ip(*args: str) -> None:
    """`ip ARGS`; a refusal becomes a LinkError that names the command."""
    done = subprocess.run(["ip", *args], capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise LinkError(f"`ip {' '.join(args)}` failed: {done.stderr.strip()}")


class TunShaper:
    """This host's packets to `route.address` through a TUN device and the hop's stages, then
    out of `route.device`. Thread-safe; `close()` removes the device and its route."""

    def __init__(
        self, name: str, route: Route, profile: LinkProfile, rng: np.random.Generator, device: str
    ) -> None:
        self.name = name
        self.route = route
        self.device = device
        self.profile = profile
        self.counters: dict[str, int] = dict.fromkeys(COUNTERS, 0)
        self.pipeline = Pipeline(profile, rng, self.counters)
        self.delays_s = Samples()  # read from the TUN to written out
        self._wire: list[tuple[float, int, float, Packet]] = []  # (leave_s, tie, read_s, packet)
        self._tie = itertools.count()
        self._cond = threading.Condition()
        self._closed = False
        self._fd = open_tun(device)
        self._wake_r, self._wake_w = os.pipe()
        try:
            mtu = Path(f"/sys/class/net/{route.device}/mtu").read_text().strip()
            ip("link", "set", device, "mtu", mtu, "up")
            ip(
                "route",
                "replace",
                f"{route.address}/32",
                "dev",
                device,
                *(["src", route.source] if route.source else []),
            )
            self._out = socket.socket(socket.AF_INET, socket.SOCK_RAW, socket.IPPROTO_RAW)
            self._out.setsockopt(socket.SOL_SOCKET, socket.SO_BINDTODEVICE, route.device.encode())
        except (LinkError, OSError) as exc:
            self._release()
            raise LinkError(f"TUN shaper {name}: {exc}") from None
        self._threads = [
            threading.Thread(target=self._read, name=f"tun-read-{name}", daemon=True),
            threading.Thread(target=self._write, name=f"tun-write-{name}", daemon=True),
        ]
        for thread in self._threads:
            thread.start()
        log.info(
            "TUN shaper %s: packets to %s through %s, then %s", name, route.address, device, route.device
        )

    def reconfigure(self, profile: LinkProfile) -> None:
        """Packets read from now on take the new profile; those on the wire keep their times."""
        with self._cond:
            self.profile = profile
            self.pipeline.configure(profile)

    def snapshot(self) -> dict[str, float]:
        with self._cond:
            stats = {k: float(v) for k, v in self.counters.items()}
            stats.update(self.delays_s.percentiles("delay", 1e3, "ms"))
            stats["on_wire"] = float(len(self._wire))
        stats["tun_tx_dropped"] = float(self._device_stat("tx_dropped"))
        return stats

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify_all()
        os.write(self._wake_w, b"x")
        for thread in self._threads:
            thread.join(timeout=1.0)
        self._out.close()
        self._release()

    def _release(self) -> None:
        for fd in (self._fd, self._wake_r, self._wake_w):
            os.close(fd)  # the TUN device, and the route through it, go with its file

    def _device_stat(self, name: str) -> int:
        try:
            return int(Path(f"/sys/class/net/{self.device}/statistics/{name}").read_text())
        except (OSError, ValueError):
            return 0

    def _read(self) -> None:
        while True:
            ready, _, _ = select.select([self._fd, self._wake_r], [], [])
            if self._wake_r in ready:
                return
            data = os.read(self._fd, 65536)
            read_s = time.monotonic()
            with self._cond:
                if not data or data[0] >> 4 != 4:  # IPv6 neighbour discovery and the like
                    self.counters["not_ipv4"] += 1
                    continue
                self.counters["packets_sent"] += 1
                self.counters["bytes_sent"] += len(data)
                header_bytes = (data[0] & 0x0F) * 4
                packet = Packet(
                    seq=0,
                    message=0,
                    index=0,
                    data=data[header_bytes:],
                    crc=0,
                    size_bytes=len(data),
                    t_s=read_s,
                    last=True,
                    head=data[:header_bytes],
                )
                for leaving in self.pipeline.run(packet):
                    heapq.heappush(self._wire, (leaving.t_s, next(self._tie), read_s, leaving))
                self._cond.notify_all()

    def _write(self) -> None:
        while True:
            with self._cond:
                while not self._closed and (not self._wire or self._wire[0][0] > time.monotonic()):
                    self._cond.wait(self._wire[0][0] - time.monotonic() if self._wire else None)
                if self._closed:
                    return
                now_s = time.monotonic()
                due = []
                while self._wire and self._wire[0][0] <= now_s:
                    _, _, read_s, packet = heapq.heappop(self._wire)
                    self.delays_s.add(now_s - read_s)
                    due.append(packet)
            for packet in due:
                self._send(packet)

    def _send(self, packet: Packet) -> None:
        try:
            self._out.sendto(packet.head + packet.data, (self.route.address, 0))
        except OSError as exc:
            with self._cond:
                self.counters["send_errors"] += 1
            log.warning("TUN shaper %s: send failed: %s", self.name, exc)
            return
        with self._cond:
            self.counters["packets_forwarded"] += 1
            self.counters["bytes_forwarded"] += len(packet.head) + len(packet.data)
            self.counters["packets_corrupted"] += packet.corrupt
