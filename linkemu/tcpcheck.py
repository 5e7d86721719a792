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
import contextlib
import json
import math
import secrets
import select
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
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
WINDOW_GRACE_S = 1.0  # the receiver reads this long past a bulk transfer's window
ACK_SEED_OFFSET = 1_000_003  # the acknowledgement direction's shaper draws its own numbers
KERNEL_BUDGET_BPS = 12e6  # what the TUN shapers of kernel runs at once may offer (a CPU's worth)
MAX_LABS = 24  # kernel runs at once, whatever their load
TOLERANCE = 0.25  # model / kernel within 1 +- TOLERANCE, widened by the measurement's spread


@dataclass(frozen=True)
class Variant:
    """A kernel TCP: the sender's congestion control (set on its socket: a namespace may only
    default to the host's allowed ones) and net.ipv4 sysctls in both namespaces."""

    congestion_control: str
    sysctls: tuple[tuple[str, str], ...] = ()


VARIANTS: dict[str, Variant] = {
    # closest to the textbook: Reno without SACK (so NewReno recovery), RACK, tail loss probes,
    # F-RTO or timestamps (so Karn's rule on retransmissions)
    "reno-textbook": Variant(
        "reno",
        (
            ("tcp_sack", "0"),
            ("tcp_dsack", "0"),
            ("tcp_recovery", "0"),
            ("tcp_early_retrans", "0"),
            ("tcp_frto", "0"),
            ("tcp_timestamps", "0"),
        ),
    ),
    # the kernel's loss recovery as it ships (SACK, RACK-TLP, PRR, F-RTO), Reno's window
    "reno": Variant("reno"),
    "cubic": Variant("cubic"),
}
COMMON_SYSCTLS = (("tcp_no_metrics_save", "1"),)  # each connection starts afresh, as each model link


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
class Phase:
    """Messages to send, (due [s from the start], size [bytes]) each; with `window_s`, only what
    the sender writes and the receiver reads in that window counts (a bulk transfer)."""

    name: str
    schedule: tuple[tuple[float, int], ...]
    window_s: float | None = None


@dataclass(frozen=True)
class Case:
    """A profile (with overrides) and its workload, sized to the rate TCP gets through it."""

    name: str
    profile: str
    hop: str  # whose lab addresses carry it
    bulk_s: float
    streams: tuple[Stream, ...]
    overrides: tuple[tuple[str, str], ...] = ()

    def link_profile(self, seed: int) -> LinkProfile:
        return profile(self.profile, {**dict(self.overrides), "seed": str(seed)})

    @property
    def phases(self) -> list[str]:
        return ["bulk", *(s.phase for s in self.streams)]

    def offered_bps(self, phase: str) -> float:
        """What a phase offers the link: all it can take in a bulk transfer."""
        if phase == "bulk":
            return self.link_profile(0).rate_bps
        stream = self._stream(phase)
        return stream.size_bytes * 8.0 / stream.interval_s

    def phase(self, name: str) -> Phase:
        if name == "bulk":  # more than the link can carry in the window
            count = math.ceil(self.bulk_s * self.link_profile(0).rate_bps / 8 / BULK_MESSAGE_BYTES) + 1
            return Phase(name, ((0.0, BULK_MESSAGE_BYTES),) * count, self.bulk_s)
        stream = self._stream(name)
        return Phase(name, tuple((i * stream.interval_s, stream.size_bytes) for i in range(stream.count)))

    def _stream(self, phase: str) -> Stream:
        return next(s for s in self.streams if s.phase == phase)


# Paces: about half of what TCP carries through each profile (the satellite at 5 % loss carries
# about 150 kbit/s, at 1 % about 450); each phase lasts 5 to 30 s.
CASES: dict[str, Case] = {
    c.name: c
    for c in (
        Case(
            "tether",
            "tether",
            "tether",
            8.0,
            (Stream(1_000, 200, 0.02), Stream(10_000, 100, 0.05), Stream(100_000, 20, 0.25)),
        ),
        Case(
            "satellite",
            "satellite",
            "satellite",
            20.0,
            (Stream(1_000, 100, 0.1), Stream(10_000, 20, 1.0), Stream(100_000, 4, 8.0)),
        ),
        Case(
            "satellite-1%",
            "satellite",
            "satellite",
            15.0,
            (Stream(1_000, 100, 0.1), Stream(10_000, 30, 0.5), Stream(100_000, 8, 3.0)),
            overrides=(("loss", "1%"),),
        ),
        # lone packets on a link of little jitter, one in ten lost: recovered when the timer fires
        # (RTO = SRTT + 200 ms, sooner than a probe), so their latency is the timer's
        Case("tether-10%", "tether", "tether", 8.0, (Stream(1_000, 40, 0.5),), overrides=(("loss", "10%"),)),
    )
}


@dataclass
class Run:
    """One phase, one way (the model or a kernel variant), one seed. Times from the phase's start."""

    phase: Phase
    deliveries: list[tuple[float, int, float]]  # (due_s, size_bytes, delivered_s) of each message
    originals: int  # data packets sent, each counted once
    retransmissions: int  # data packets sent again
    timeouts: int  # retransmission timer expiries
    extra: dict[str, float] = field(default_factory=dict)  # shaper and kernel counters, for the record

    def metrics(self) -> dict[str, float]:
        per_packet = {
            "retrans_per_packet": self.retransmissions / max(1, self.originals),
            "timeouts_per_packet": self.timeouts / max(1, self.originals),
            "packets": float(self.originals),
        }
        if self.phase.window_s is not None:
            window_s = self.phase.window_s
            delivered_bytes = sum(size for _, size, t_s in self.deliveries if t_s <= window_s)
            return {"goodput_bps": delivered_bytes * 8.0 / window_s, **per_packet}
        latencies_s = [delivered - due for due, _, delivered in self.deliveries]
        p50, p95 = np.percentile(latencies_s, [50, 95])
        return {"latency_p50_s": float(p50), "latency_p95_s": float(p95), **per_packet}


@dataclass(frozen=True)
class Job:
    """One run to make: `way` is "model" or a kernel variant."""

    way: str
    case: str
    phase: str
    seed: int

    def __str__(self) -> str:
        return f"{self.way} {self.case} {self.phase} seed {self.seed}"


def run(job: Job) -> Run:
    case = CASES[job.case]
    if job.way == "model":
        return run_model(case, case.phase(job.phase), job.seed)
    return run_kernel(case, job.way, case.phase(job.phase), job.seed)


def run_all(jobs: Sequence[Job], echo: Callable[[str], None] = lambda _: None) -> dict[Job, Run]:
    """Every job: the model's in turn, then the kernel's, a lab each, as many at once as the
    shapers can carry (their offered loads within KERNEL_BUDGET_BPS, at most MAX_LABS labs);
    `echo` hears of each as it ends. A kernel run that fails is told to `echo` and left out."""
    runs: dict[Job, Run] = {}
    started_s = time.monotonic()
    for job in jobs:
        if job.way == "model":
            runs[job] = run(job)
    echo(f"[{len(runs)}/{len(jobs)}] the model's runs ({time.monotonic() - started_s:.1f} s)")

    def load_bps(job: Job) -> float:
        return min(CASES[job.case].offered_bps(job.phase), KERNEL_BUDGET_BPS)

    in_use_bps = [0.0]
    budget = threading.Condition()

    def one(job: Job) -> None:
        with budget:
            budget.wait_for(lambda: in_use_bps[0] + load_bps(job) <= KERNEL_BUDGET_BPS)
            in_use_bps[0] += load_bps(job)
        job_started_s = time.monotonic()
        try:
            runs[job] = run(job)
        except (LinkError, OSError, subprocess.SubprocessError, ValueError) as exc:
            echo(f"[{len(runs)}/{len(jobs)}] {job}: FAILED, left out: {exc}")
            return
        finally:
            with budget:
                in_use_bps[0] -= load_bps(job)
                budget.notify_all()
        figures = ", ".join(f"{k} {v:.3g}" for k, v in runs[job].metrics().items())
        echo(f"[{len(runs)}/{len(jobs)}] {job}: {figures} ({time.monotonic() - job_started_s:.1f} s)")

    kernel = sorted((job for job in jobs if job.way != "model"), key=load_bps, reverse=True)
    with ThreadPoolExecutor(MAX_LABS) as pool:
        list(pool.map(one, kernel))
    return {job: runs[job] for job in jobs if job in runs}


@dataclass(frozen=True)
class Agreement:
    """Model against kernel on one metric, each over its seeds. They agree when their means differ
    by at most TOLERANCE of the kernel's, plus `z` standard errors of the difference, plus
    `resolution` (a per-packet count's: one event per run, so that 0 against 1 in 200 agrees)."""

    model: tuple[float, ...]
    kernel: tuple[float, ...]
    resolution: float = 0.0
    z: float = 2.0

    @property
    def ratio(self) -> float:
        return _mean(self.model) / _mean(self.kernel) if _mean(self.kernel) else math.inf

    @property
    def allowed(self) -> float:
        """The largest difference of the means that agrees."""
        spread = math.hypot(_sem(self.model), _sem(self.kernel))
        return TOLERANCE * abs(_mean(self.kernel)) + self.z * spread + self.resolution

    @property
    def agrees(self) -> bool:
        return abs(_mean(self.model) - _mean(self.kernel)) <= self.allowed


def agreement(
    metric: str, model: Sequence[Mapping[str, float]], kernel: Sequence[Mapping[str, float]]
) -> Agreement:
    """`metric` of one phase's runs (as `Run.metrics()` gives them), the model's against the kernel's."""
    resolution = 1.0 / _mean([r["packets"] for r in kernel]) if metric.endswith("_per_packet") else 0.0
    return Agreement(tuple(r[metric] for r in model), tuple(r[metric] for r in kernel), resolution)


def _mean(values: Sequence[float]) -> float:
    return float(np.mean(values))


def _sem(values: Sequence[float]) -> float:
    return float(np.std(values, ddof=1) / math.sqrt(len(values))) if len(values) > 1 else 0.0


# -- the model ---------------------------------------------------------------------------------
def run_model(case: Case, phase: Phase, seed: int) -> Run:
    """The phase through `Link` (transport tcp) with made-up times: each message offered when it
    is due, or as soon as the sender's queue has room (and before the window ends)."""
    link = Link(case.link_profile(seed))
    end_s = phase.window_s if phase.window_s is not None else math.inf
    deliveries: list[tuple[float, int, float]] = []
    now_s = 0.0

    def run_until(t_s: float) -> None:
        nonlocal now_s
        now_s = max(now_s, t_s)
        deliveries.extend((d.tag[0], d.tag[1], d.delivered_s) for d in link.advance(now_s))

    for due_s, size in phase.schedule:
        run_until(due_s)
        while now_s < end_s and link.offer(now_s, bytes(size), block=True, tag=(due_s, size)) is Offer.FULL:
            next_s = link.next_event_s()
            if next_s is None:
                raise LinkError(f"{case.name} {phase.name}: the model's queue is full with nothing in flight")
            run_until(min(next_s, end_s))
    while now_s < end_s and (next_s := link.next_event_s()) is not None:
        run_until(min(next_s, end_s))
    retransmissions = link.counters["retransmissions"]
    return Run(
        phase,
        deliveries,
        link.counters["packets_sent"] - retransmissions,
        retransmissions,
        link.counters["timeouts"],
        {"losses": link.counters["losses"], "queue_drops": link.counters["queue_drops"]},
    )


# -- kernel TCP --------------------------------------------------------------------------------
def kernel_unusable() -> str:
    """Why kernel runs cannot be made here ('' when they can)."""
    from abyss.launch.lab import usable

    if reason := usable():
        return reason
    if not Path("/dev/net/tun").exists():
        return "no /dev/net/tun (modprobe tun) for the TUN shaper"
    available = Path("/proc/sys/net/ipv4/tcp_available_congestion_control").read_text().split()
    wanted = {v.congestion_control for v in VARIANTS.values()}
    if missing := wanted - set(available):
        return f"congestion control {', '.join(sorted(missing))} not loaded (modprobe tcp_{min(missing)})"
    return ""


_starting = threading.Lock()


def run_kernel(case: Case, variant: str, phase: Phase, seed: int, timeout_s: float = 120.0) -> Run:
    """The phase through kernel TCP in a lab of its own, made and removed here."""
    from abyss.common import keys
    from abyss.launch.lab import Lab

    lab = Lab(f"tcp{secrets.token_hex(4)}")
    sender, receiver = keys.HOPS[case.hop]
    started: list[subprocess.Popen[str]] = []
    window = [f"--window={phase.window_s}"] if phase.window_s is not None else []

    def start(command: list[str]) -> subprocess.Popen[str]:
        process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        started.append(process)
        _first_line(process, START_TIMEOUT_S)
        return process

    try:
        with _starting:  # one lab at a time: starting programs takes a CPU from the labs running
            lab.make(echo=None)
            sysctls = [f"net.ipv4.{k}={v}" for k, v in (*COMMON_SYSCTLS, *VARIANTS[variant].sysctls)]
            for station in (sender, receiver):
                _check([*lab.prefix(station), "sysctl", "-q", "-w", *sysctls])
            fields = [f"--{k}={v}" for k, v in case.overrides]
            shapers = [
                start(
                    lab.shape(
                        station,
                        case.hop,
                        case.profile,
                        *fields,
                        f"--seed={shaper_seed}",
                        "--every=3600",
                        f"--duration={timeout_s}",
                    )
                )
                for station, shaper_seed in ((sender, seed), (receiver, seed + ACK_SEED_OFFSET))
            ]
            listening = start(
                [
                    *lab.prefix(receiver),
                    sys.executable,
                    "-P",
                    "-m",
                    __name__,
                    "receive",
                    f"--timeout={timeout_s}",
                    *window,
                ]
            )
        sent = subprocess.run(
            [
                *lab.prefix(sender),
                sys.executable,
                "-P",
                "-m",
                __name__,
                "send",
                f"--to={lab.address(receiver, case.hop)}",
                f"--timeout={timeout_s}",
                f"--congestion-control={VARIANTS[variant].congestion_control}",
                *window,
            ],
            input=json.dumps(phase.schedule),
            capture_output=True,
            text=True,
            timeout=timeout_s + START_TIMEOUT_S,
            check=False,
        )
        if sent.returncode != 0:
            raise LinkError(
                f"kernel {variant} {case.name} {phase.name}: the sender failed: {sent.stderr.strip()[-2000:]}"
            )
        report = json.loads(sent.stdout)
        received = json.loads(_finish(listening)[-1])
        shaped = [json.loads(_finish(shaper, signal.SIGTERM)[-1]) for shaper in shapers]
    finally:
        for process in started:
            if process.poll() is None:
                process.kill()
                process.wait()
        lab.remove()
    t0_s, counters = report["t0_s"], report["counters"]
    extra = {
        **{f"kernel_{k}": float(v) for k, v in counters.items()},
        **{
            f"{way}_{k}": shaped[i][k]
            for i, way in enumerate(("data", "ack"))
            for k in ("losses", "queue_drops", "packets_corrupted", "tun_tx_dropped")
        },
    }
    return Run(
        phase,
        [(due - t0_s, size, at - t0_s) for due, size, at in received],
        counters["TcpExtTCPOrigDataSent"],
        counters["TcpRetransSegs"],
        counters["TcpExtTCPTimeouts"],
        extra,
    )


def _check(command: list[str]) -> None:
    done = subprocess.run(command, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise LinkError(f"`{' '.join(command)}` failed: {done.stderr.strip()}")


def _command_line(process: subprocess.Popen[str]) -> str:
    args = process.args
    return " ".join(map(str, args)) if isinstance(args, list | tuple) else str(args)


def _first_line(process: subprocess.Popen[str], timeout_s: float) -> str:
    """The first line a program prints (it says it is ready), within `timeout_s`."""
    assert process.stdout is not None
    ready, _, _ = select.select([process.stdout], [], [], timeout_s)
    line = process.stdout.readline() if ready else ""
    if not line:
        process.kill()
        _, err = process.communicate()
        raise LinkError(f"`{_command_line(process)}` did not start: {err.strip()[-2000:]}")
    return line


def _finish(process: subprocess.Popen[str], stop: signal.Signals | None = None) -> list[str]:
    """The rest of a program's output, line by line, once it has ended (after `stop`, if given)."""
    if stop is not None:
        process.send_signal(stop)
    out, err = process.communicate(timeout=10.0)
    if process.returncode != 0:
        raise LinkError(f"`{_command_line(process)}` failed: {err.strip()[-2000:]}")
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
                numbers = values.split()[1:]
                counters.update({kind[:-1] + k: int(v) for k, v in zip(keys, numbers, strict=True)})
    return counters


def send(
    address: str,
    schedule: Sequence[tuple[float, int]],
    congestion_control: str,
    window_s: float | None,
    timeout_s: float,
) -> dict[str, object]:
    """Connect with `congestion_control`; send each message when it is due (no Nagle delay) and
    wait until the receiver has read everything, or, with `window_s`, send until then and reset the
    connection. When it started and this namespace's counters at the end."""
    before = tcp_counters()
    deadline_s = time.monotonic() + START_TIMEOUT_S
    while True:
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_CONGESTION, congestion_control.encode())
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        try:
            sock.settimeout(timeout_s)
            sock.connect((address, PORT))
            break
        except OSError:
            sock.close()
            if time.monotonic() > deadline_s:
                raise
            time.sleep(0.05)
    with sock:
        t0_s = time.monotonic()
        end_s = t0_s + (window_s if window_s is not None else timeout_s)
        try:
            for offset_s, size in schedule:
                time.sleep(max(0.0, t0_s + offset_s - time.monotonic()))
                sock.settimeout(max(1e-3, end_s - time.monotonic()))
                sock.sendall(HEADER.pack(size, t0_s + offset_s).ljust(size, b"\0"))
            sock.shutdown(socket.SHUT_WR)
            sock.recv(1)  # the receiver closes once it has read everything
        except TimeoutError:
            if window_s is None:
                raise
        after = tcp_counters()
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))  # close: reset
    return {"t0_s": t0_s, "counters": {k: after[k] - before[k] for k in after}}


def receive(window_s: float | None, timeout_s: float) -> list[tuple[float, int, float]]:
    """Accept one connection; (due_s, size_bytes, delivered_s) of each message read from it until
    the sender closes it or, with `window_s`, until that long after the first message was due
    (the sender's reset may be lost on the way)."""
    with socket.create_server(("0.0.0.0", PORT)) as listener:
        print("ready", flush=True)
        listener.settimeout(timeout_s)
        conn, _ = listener.accept()
    out: list[tuple[float, int, float]] = []
    buffer = bytearray()
    end_s = time.monotonic() + timeout_s
    with conn, contextlib.suppress(ConnectionResetError, TimeoutError):
        while True:
            conn.settimeout(max(1e-3, end_s - time.monotonic()))
            chunk = conn.recv(1 << 20)
            if not chunk:
                break
            now_s = time.monotonic()
            buffer += chunk
            while len(buffer) >= HEADER.size and len(buffer) >= (size := HEADER.unpack_from(buffer)[0]):
                due_s = HEADER.unpack_from(buffer)[1]
                if not out and window_s is not None:
                    end_s = due_s + window_s + WINDOW_GRACE_S
                out.append((due_s, size, now_s))
                del buffer[:size]
    return out


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m abyss.linkemu.tcpcheck")
    sub = parser.add_subparsers(dest="role", required=True)
    s = sub.add_parser("send")
    s.add_argument("--to", required=True)
    s.add_argument("--congestion-control", required=True)
    s.add_argument("--window", type=float, help="send until then [s], then reset the connection")
    r = sub.add_parser("receive")
    r.add_argument("--window", type=float, help="read until then [s] after the first message was due")
    for p in (s, r):
        p.add_argument("--timeout", type=float, default=120.0)
    args = parser.parse_args(argv)
    if args.role == "send":
        report = send(args.to, json.load(sys.stdin), args.congestion_control, args.window, args.timeout)
        print(json.dumps(report))
    else:
        print(json.dumps(receive(args.window, args.timeout)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
