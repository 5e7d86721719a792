"""The TCP model against kernel TCP: one workload, on the same profile and seed, two ways.

(a) The model: a `Link` with transport tcp, driven with made-up times (a second of CPU).
(b) Kernel TCP between two namespaces of a throw-away lab (`launch.lab.Lab`), each direction
    shaped by its sender's TUN shaper (`abyss link shape`, the same stages as the model's link:
    data one way, acknowledgements the other). This module's `send` and `receive` programs run
    in the namespaces (`ip netns exec`); CLOCK_MONOTONIC is shared across network namespaces, so
    the receiver measures one-way latency against the sender's schedule directly, and the
    sender's namespace counters (/proc/net/snmp, /proc/net/netstat) count its retransmissions
    (RetransSegs), timeouts (TCPTimeouts) and first transmissions (TCPOrigDataSent).

A case's workload, each phase on a new connection (and a new model link): a bulk transfer
(goodput, retransmissions and timeouts per packet) and streams of 1, 10 and 100 kB messages at
a pace the link carries (delivery latency p50/p95: from when a message was due to when its last
byte reached the receiving application).
"""

from __future__ import annotations

import argparse
import json
import math
import secrets
import select
import signal
import socket
import struct
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from abyss.common.errors import LinkError
from abyss.linkemu.link import Link, Offer
from abyss.linkemu.profile import LinkProfile, profile

PORT = 5201
HEADER = struct.Struct("!Id")  # a message's size [bytes] and when it was due [s, CLOCK_MONOTONIC]
BULK_MESSAGE_BYTES = 14_600  # ten whole model packets
START_TIMEOUT_S = 20.0  # a shaper or the receiver ready, the connection made
ACK_SEED_OFFSET = 1_000_003  # the acknowledgement direction's shaper draws its own numbers

# Kernel TCP variants: net.ipv4 sysctls set in both namespaces, on top of COMMON_SYSCTLS.
VARIANTS: dict[str, dict[str, str]] = {
    # closest to the textbook: Reno without SACK (so NewReno recovery), RACK, tail loss probes,
    # F-RTO or timestamps (so Karn's rule on retransmissions)
    "reno-textbook": {"tcp_congestion_control": "reno", "tcp_sack": "0", "tcp_dsack": "0",
                      "tcp_recovery": "0", "tcp_early_retrans": "0", "tcp_frto": "0",
                      "tcp_timestamps": "0"},
    # the kernel's loss recovery as it ships (SACK, RACK-TLP, PRR, F-RTO), Reno's window
    "reno": {"tcp_congestion_control": "reno"},
    "cubic": {"tcp_congestion_control": "cubic"},
}
COMMON_SYSCTLS = {"tcp_no_metrics_save": "1"}  # each connection starts afresh, as each model link


@dataclass(frozen=True)
class Stream:
    """Messages of one size, one every `interval_s`."""

    size_bytes: int
    count: int
    interval_s: float

    @property
    def phase(self) -> str:
        return f"{self.size_bytes // 1000}kB"


@dataclass(frozen=True)
class Case:
    """A profile (with overrides) and its workload, sized to the rate TCP gets through it."""

    name: str
    profile: str
    hop: str  # whose lab addresses carry it
    bulk_bytes: int
    streams: tuple[Stream, ...]
    overrides: tuple[tuple[str, str], ...] = ()

    def link_profile(self, seed: int) -> LinkProfile:
        return profile(self.profile, {**dict(self.overrides), "seed": str(seed)})

    @property
    def phases(self) -> list[str]:
        return ["bulk", *(s.phase for s in self.streams)]

    def schedule(self, phase: str) -> list[tuple[float, int]]:
        """(due [s from the start], size [bytes]) of each message of a phase."""
        if phase == "bulk":
            return [(0.0, BULK_MESSAGE_BYTES)] * math.ceil(self.bulk_bytes / BULK_MESSAGE_BYTES)
        stream = next(s for s in self.streams if s.phase == phase)
        return [(i * stream.interval_s, stream.size_bytes) for i in range(stream.count)]


# Paces: about half of what TCP carries through each profile (the satellite at 5 % loss carries
# about 150 kbit/s, at 1 % about 450); each phase lasts 5 to 25 s on the kernel's side.
CASES: dict[str, Case] = {c.name: c for c in (
    Case("tether", "tether", "tether", 12_000_000,
         (Stream(1_000, 200, 0.02), Stream(10_000, 100, 0.05), Stream(100_000, 20, 0.25))),
    Case("satellite", "satellite", "satellite", 250_000,
         (Stream(1_000, 100, 0.1), Stream(10_000, 20, 1.0), Stream(100_000, 5, 5.0))),
    Case("satellite-1%", "satellite", "satellite", 500_000,
         (Stream(1_000, 100, 0.1), Stream(10_000, 30, 0.5), Stream(100_000, 10, 2.5)),
         overrides=(("loss", "1%"),)),
)}


@dataclass
class Run:
    """One phase, one way (the model or a kernel variant), one seed. Times from the phase's start."""

    deliveries: list[tuple[float, int, float]]  # (due_s, size_bytes, delivered_s) of each message
    originals: int  # data packets sent, each counted once
    retransmissions: int  # data packets sent again
    timeouts: int  # retransmission timer expiries
    extra: dict[str, float] = field(default_factory=dict)  # shaper and kernel counters, for the record

    def metrics(self, phase: str) -> dict[str, float]:
        per_packet = {"retrans_per_packet": self.retransmissions / max(1, self.originals),
                      "timeouts_per_packet": self.timeouts / max(1, self.originals)}
        if phase == "bulk":
            total_bytes = sum(size for _, size, _ in self.deliveries)
            return {"goodput_bps": total_bytes * 8.0 / max(t for _, _, t in self.deliveries), **per_packet}
        latencies_s = [delivered - due for due, _, delivered in self.deliveries]
        p50, p95 = np.percentile(latencies_s, [50, 95])
        return {"latency_p50_s": float(p50), "latency_p95_s": float(p95), **per_packet}


# -- the model ---------------------------------------------------------------------------------
def run_model(case: Case, phase: str, seed: int) -> Run:
    """The phase through `Link` (transport tcp) with made-up times: each message offered when it
    is due, or as soon as the sender's queue has room."""
    link = Link(case.link_profile(seed))
    deliveries: list[tuple[float, int, float]] = []
    now_s = 0.0

    def collect() -> None:
        deliveries.extend((d.tag[0], d.tag[1], d.delivered_s) for d in link.advance(now_s))

    schedule = case.schedule(phase)
    for due_s, size in schedule:
        now_s = max(now_s, due_s)
        collect()
        while link.offer(now_s, bytes(size), block=True, tag=(due_s, size)) is Offer.FULL:
            next_s = link.next_event_s()
            if next_s is None:
                raise LinkError(f"{case.name} {phase}: the model's queue is full with nothing in flight")
            now_s = max(now_s, next_s)
            collect()
    while (next_s := link.next_event_s()) is not None:
        now_s = max(now_s, next_s)
        collect()
    originals = sum(link.packets_for(size) for _, size in schedule)
    return Run(deliveries, originals, link.counters["packets_sent"] - originals, link.counters["timeouts"],
               {"losses": link.counters["losses"], "queue_drops": link.counters["queue_drops"]})


# -- kernel TCP --------------------------------------------------------------------------------
def kernel_unusable() -> str:
    """Why kernel runs cannot be made here ('' when they can)."""
    from abyss.launch.lab import usable

    if reason := usable():
        return reason
    if not Path("/dev/net/tun").exists():
        return "no /dev/net/tun (modprobe tun) for the TUN shaper"
    available = Path("/proc/sys/net/ipv4/tcp_available_congestion_control").read_text().split()
    wanted = {v["tcp_congestion_control"] for v in VARIANTS.values()}
    if missing := wanted - set(available):
        return f"congestion control {', '.join(sorted(missing))} not loaded (modprobe tcp_{min(missing)})"
    return ""


def run_kernel(case: Case, variant: str, phase: str, seed: int, timeout_s: float = 120.0) -> Run:
    """The phase through kernel TCP in a lab of its own, made and removed here."""
    from abyss.common import keys
    from abyss.launch.lab import Lab

    lab = Lab(f"tcp{secrets.token_hex(4)}")
    sender, receiver = keys.HOPS[case.hop]
    started: list[subprocess.Popen[str]] = []

    def start(station: str, *args: str) -> subprocess.Popen[str]:
        process = subprocess.Popen([*lab.prefix(station), sys.executable, "-P", *args],
                                   stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        started.append(process)
        _first_line(process, START_TIMEOUT_S)
        return process

    try:
        lab.make(echo=None)
        sysctls = [f"net.ipv4.{k}={v}" for k, v in {**COMMON_SYSCTLS, **VARIANTS[variant]}.items()]
        for station in (sender, receiver):
            _check([*lab.prefix(station), "sysctl", "-q", "-w", *sysctls])
        shapers = [start(station, "-m", "abyss.cli", "link", "shape", case.hop,
                         "--peer", lab.address(peer, case.hop), "--profile", case.profile,
                         *(f"--{k}={v}" for k, v in case.overrides), f"--seed={seed + offset}",
                         "--every=3600", f"--duration={timeout_s}")
                   for station, peer, offset in ((sender, receiver, 0), (receiver, sender, ACK_SEED_OFFSET))]
        listening = start(receiver, "-m", __name__, "receive", f"--timeout={timeout_s}")
        sent = subprocess.run(
            [*lab.prefix(sender), sys.executable, "-P", "-m", __name__, "send",
             f"--to={lab.address(receiver, case.hop)}", f"--timeout={timeout_s}",
             "--schedule", json.dumps(case.schedule(phase))],
            capture_output=True, text=True, timeout=timeout_s + START_TIMEOUT_S, check=False)
        if sent.returncode != 0:
            raise LinkError(f"kernel {variant} {case.name} {phase}: the sender failed: {sent.stderr.strip()}")
        report = json.loads(sent.stdout)
        received = json.loads(_finish(listening)[-1])
        shaped = [json.loads(_finish(shaper, signal.SIGTERM)[-1]) for shaper in shapers]
    finally:
        for process in started:
            if process.poll() is None:
                process.kill()
                process.wait()
        lab.remove()
    if report["congestion_control"] != VARIANTS[variant]["tcp_congestion_control"]:
        raise LinkError(f"the kernel used {report['congestion_control']}, not {variant}'s")
    t0_s, counters = report["t0_s"], report["counters"]
    extra = {**{f"kernel_{k}": float(v) for k, v in counters.items()},
             **{f"{way}_{k}": shaped[i][k] for i, way in enumerate(("data", "ack"))
                for k in ("losses", "queue_drops", "packets_corrupted", "tun_tx_dropped")}}
    return Run([(due - t0_s, size, at - t0_s) for due, size, at in received],
               counters["TcpExtTCPOrigDataSent"], counters["TcpRetransSegs"], counters["TcpExtTCPTimeouts"],
               extra)


def _check(command: list[str]) -> None:
    done = subprocess.run(command, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise LinkError(f"`{' '.join(command)}` failed: {done.stderr.strip()}")


def _first_line(process: subprocess.Popen[str], timeout_s: float) -> str:
    """The first line a program prints (it says it is ready), within `timeout_s`."""
    assert process.stdout is not None
    ready, _, _ = select.select([process.stdout], [], [], timeout_s)
    line = process.stdout.readline() if ready else ""
    if not line:
        process.kill()
        _, err = process.communicate()
        raise LinkError(f"`{' '.join(map(str, process.args))}` did not start: {err.strip()[-2000:]}")
    return line


def _finish(process: subprocess.Popen[str], stop: signal.Signals | None = None) -> list[str]:
    """The rest of a program's output, line by line, once it has ended (after `stop`, if given)."""
    if stop is not None:
        process.send_signal(stop)
    out, err = process.communicate(timeout=10.0)
    if process.returncode != 0:
        raise LinkError(f"`{' '.join(map(str, process.args))}` failed: {err.strip()[-2000:]}")
    return out.splitlines() or [""]


# -- the programs that run in the namespaces ----------------------------------------------------
def tcp_counters() -> dict[str, int]:
    """This namespace's TCP counters: {"TcpRetransSegs": ..., "TcpExtTCPTimeouts": ...}."""
    counters: dict[str, int] = {}
    for path in ("/proc/net/snmp", "/proc/net/netstat"):
        lines = Path(path).read_text().splitlines()
        for names, values in zip(lines[::2], lines[1::2], strict=True):
            kind, *keys = names.split()
            if kind in ("Tcp:", "TcpExt:"):
                counters.update({kind[:-1] + k: int(v) for k, v in zip(keys, values.split()[1:], strict=True)})
    return counters


def send(address: str, schedule: Sequence[tuple[float, int]], timeout_s: float) -> dict[str, object]:
    """Connect, send each message when it is due (no Nagle delay), wait until the receiver has
    read everything; the connection's congestion control and this namespace's counters."""
    before = tcp_counters()
    deadline_s = time.monotonic() + START_TIMEOUT_S
    while True:
        try:
            sock = socket.create_connection((address, PORT), timeout=timeout_s)
            break
        except OSError:
            if time.monotonic() > deadline_s:
                raise
            time.sleep(0.05)
    with sock:
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        congestion = sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_CONGESTION, 16)
        t0_s = time.monotonic()
        for offset_s, size in schedule:
            time.sleep(max(0.0, t0_s + offset_s - time.monotonic()))
            sock.sendall(HEADER.pack(size, t0_s + offset_s).ljust(size, b"\0"))
        sock.shutdown(socket.SHUT_WR)
        sock.recv(1)  # the receiver closes once it has read everything
    after = tcp_counters()
    return {"t0_s": t0_s, "congestion_control": congestion.rstrip(b"\0").decode(),
            "counters": {k: after[k] - before[k] for k in after}}


def receive(timeout_s: float) -> list[tuple[float, int, float]]:
    """Accept one connection; (due_s, size_bytes, delivered_s) of each message read from it."""
    with socket.create_server(("0.0.0.0", PORT)) as listener:
        print("ready", flush=True)
        listener.settimeout(timeout_s)
        conn, _ = listener.accept()
    out: list[tuple[float, int, float]] = []
    buffer = bytearray()
    with conn:
        conn.settimeout(timeout_s)
        while chunk := conn.recv(1 << 20):
            now_s = time.monotonic()
            buffer += chunk
            while len(buffer) >= HEADER.size and len(buffer) >= (size := HEADER.unpack_from(buffer)[0]):
                out.append((HEADER.unpack_from(buffer)[1], size, now_s))
                del buffer[:size]
    return out


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m abyss.linkemu.tcpcheck")
    sub = parser.add_subparsers(dest="role", required=True)
    s = sub.add_parser("send")
    s.add_argument("--to", required=True)
    s.add_argument("--schedule", required=True, help="JSON [[due_s, size_bytes], ...]")
    r = sub.add_parser("receive")
    for p in (s, r):
        p.add_argument("--timeout", type=float, default=120.0)
    args = parser.parse_args(argv)
    if args.role == "send":
        print(json.dumps(send(args.to, json.loads(args.schedule), args.timeout)))
    else:
        print(json.dumps(receive(args.timeout)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
