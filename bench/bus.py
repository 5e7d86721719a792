"""Bus figures: bus/session.py against raw zenoh-python in the same run, and `abyss up`
start-up time. Run: .venv/bin/python bench/bus.py [--startup-runs N]. Prints figures; asserts nothing.

Each case opens two Zenoh peer sessions in this process over loopback TCP. The bus side
publishes through the hop's emulator with the `ideal` profile (the counted pass-through)
and decodes and validates every message on receipt; the raw side puts the same encoded
bytes (plus an 8-byte send time) and only counts them, once with Zenoh's default priority
and no express (`raw`), once with the key's own priority and express, as the bus declares
it (`raw/qos`). Cases: a flood of small messages (capacity in messages/s), a flood of 32 KB
messages (capacity in bit/s), and small messages paced at 500/s (latency without queueing).
A flood's capacity is what arrived over the time until the last arrival: with congestion
control DROP, Zenoh drops some of a flood (`delivered` says how much arrived)."""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import zenoh

from abyss.bus.session import open_session, zenoh_config
from abyss.common.samples import Samples
from abyss.config import Config
from abyss.config.system import LinksConfig
from abyss.interface import keys
from abyss.interface.messages import Message, NavState, Waypoints, encode
from abyss.interface.qos import publisher_qos
from abyss.launch.station import Shell, free_port

SYSTEM = "bench"
QUIET_S = 0.5  # a flood is over when nothing more arrived for this long


@dataclass(frozen=True)
class Case:
    name: str
    publisher: str
    topic: str
    message: Message
    count: int
    rate_hz: float | None  # None: as fast as possible


@dataclass(frozen=True)
class Result:
    messages_per_s: float
    bits_per_s: float
    latency_p50_us: float
    latency_p99_us: float
    delivered: float  # the share of the messages sent that arrived


CASES = (
    Case(
        "flood, NavState",
        "simulation",
        "nav",
        NavState(np.zeros(3), np.array([1.0, 0, 0, 0]), np.zeros(3), np.zeros(3), 0.0),
        20000,
        None,
    ),
    Case("flood, Waypoints 32 KB", "vessel", "goal/waypoints", Waypoints(1, np.zeros((1000, 4))), 2000, None),
    Case(
        "paced 500/s, NavState",
        "simulation",
        "nav",
        NavState(np.zeros(3), np.array([1.0, 0, 0, 0]), np.zeros(3), np.zeros(3), 0.0),
        3000,
        500.0,
    ),
)


def drive(case: Case, publish: Callable[[], object], received: Callable[[], int], latency: Samples) -> Result:
    for _ in range(100):  # warm up
        publish()
    time.sleep(0.5)
    start = received()
    latency.__init__()  # type: ignore[misc]
    t0 = time.perf_counter()
    for i in range(case.count):
        if case.rate_hz:
            time.sleep(max(0.0, t0 + i / case.rate_hz - time.perf_counter()))
        publish()
    deadline = time.perf_counter() + 20
    n, last_arrival = received() - start, time.perf_counter()
    while n < case.count and time.perf_counter() - last_arrival < QUIET_S and time.perf_counter() < deadline:
        time.sleep(0.005)
        if received() - start > n:
            n, last_arrival = received() - start, time.perf_counter()
    elapsed = last_arrival - t0
    size = len(encode(case.message, 0, 0.0))
    lat = latency.percentiles("latency", 1e6, "us", (50, 99))
    return Result(
        n / elapsed, n * size * 8 / elapsed, lat["latency_p50_us"], lat["latency_p99_us"], n / case.count
    )


def bench_bus(case: Case) -> Result:
    port = free_port()
    spec = keys.spec(case.publisher, case.topic)
    ideal = Config(links=LinksConfig("ideal", "ideal", "ideal"), system=SYSTEM)
    sending = Shell(case.publisher, ideal, listen=[f"tcp/127.0.0.1:{port}"])
    receiving = Shell(spec.to, ideal, connect=[f"tcp/127.0.0.1:{port}"])
    sender, receiver = sending.bus, receiving.bus
    receiver.subscribe(case.publisher, case.topic, spec.message_class, maxlen=8)
    key = spec.key(SYSTEM)
    receiver.latency_s[key] = latency = Samples()
    time.sleep(1.0)
    result = drive(
        case, lambda: sender.publish(case.topic, case.message), lambda: receiver.received[key], latency
    )
    sending.close()
    receiving.close()
    return result


def bench_raw(case: Case, key_qos: bool) -> Result:
    port = free_port()
    a = open_session(zenoh_config(listen=[f"tcp/127.0.0.1:{port}"]), "raw a")
    b = open_session(zenoh_config(connect=[f"tcp/127.0.0.1:{port}"]), "raw b")
    count = [0]
    latency = Samples()

    def on_sample(sample: zenoh.Sample) -> None:
        data = sample.payload.to_bytes()
        latency.add(time.time() - float(np.frombuffer(data[-8:], "<f8")[0]))
        count[0] += 1

    qos = publisher_qos(keys.spec(case.publisher, case.topic))
    if not key_qos:
        qos = {"congestion_control": qos["congestion_control"]}
    sub = b.declare_subscriber("abyss/bench/raw", on_sample)
    pub = a.declare_publisher("abyss/bench/raw", **qos)
    time.sleep(1.0)
    body = encode(case.message, 0, 0.0)
    result = drive(case, lambda: pub.put(body + np.float64(time.time()).tobytes()), lambda: count[0], latency)
    sub.undeclare()
    pub.undeclare()
    a.close()
    b.close()
    return result


def bench_startup(runs: int = 3) -> list[float]:
    times = []
    for i in range(runs):
        out = Path("runs") / f"bench-startup-{i}"
        done = subprocess.run(
            [
                sys.executable,
                "-m",
                "abyss.cli",
                "up",
                "--duration",
                "1",
                "--port",
                "0",
                "--out",
                str(out),
                "--system",
                f"bench{i}",
            ],
            capture_output=True,
            text=True,
        )
        m = re.search(r"all 4 stations up in ([0-9.]+) s", done.stdout)
        if m:
            times.append(float(m.group(1)))
    return times


def show(label: str, r: Result) -> None:
    print(
        f"  {label:<7} {r.messages_per_s:9.0f} msg/s {r.bits_per_s / 1e6:9.1f} Mbit/s   "
        f"latency p50 {r.latency_p50_us:9.0f} us  p99 {r.latency_p99_us:9.0f} us   "
        f"delivered {100 * r.delivered:5.1f} %"
    )


def compare(label: str, bus: Result, raw: Result) -> None:
    extra_us = bus.latency_p50_us - raw.latency_p50_us
    print(
        f"  bus/{label}: throughput {bus.messages_per_s / raw.messages_per_s:.2f}x, latency p50 "
        f"{bus.latency_p50_us / raw.latency_p50_us:.2f}x ({extra_us:+.0f} us), "
        f"p99 {bus.latency_p99_us / raw.latency_p99_us:.2f}x"
    )


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--startup-runs", type=int, default=3, help="`abyss up` runs timed (0: none)")
    args = parser.parse_args()
    for case in CASES:
        raw, raw_qos, bus = bench_raw(case, key_qos=False), bench_raw(case, key_qos=True), bench_bus(case)
        print(case.name)
        show("raw", raw)
        show("raw/qos", raw_qos)
        show("bus", bus)
        compare("raw", bus, raw)
        compare("raw/qos", bus, raw_qos)
    if args.startup_runs:
        startup = bench_startup(args.startup_runs)
        print(f"abyss up, command to all four stations alive: {', '.join(f'{t:.2f}' for t in startup)} s")
