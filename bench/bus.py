"""Bus figures: common/bus.py against raw zenoh-python in the same run, and `abyss up`
start-up time. Run: .venv/bin/python bench/bus.py. Prints figures; asserts nothing.

Both sides run two Zenoh peer sessions in one process over loopback TCP; the bus side
publishes NavState through the `rov` hop's emulator (ideal profile: the pass-through) and
decodes and validates on receipt; the raw side puts and receives the same bytes."""

from __future__ import annotations

import re
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import zenoh

from common.bus import Bus, open_session, zenoh_config
from common.messages import NavState, Received, encode
from linkemu.profile import profile
from stations.runtime import free_port

N = 20000
SYSTEM = "bench"


def nav() -> NavState:
    return NavState(np.zeros(3), np.array([1.0, 0, 0, 0]), np.zeros(3), np.zeros(3), 0.0)


def measure(publish: Callable[[], object], received: list[tuple[float, float]]) -> tuple[float, float, float]:
    """Publish N messages as fast as possible; messages/s and one-way latency p50, p99 [us]."""
    for _ in range(200):  # warm up
        publish()
    time.sleep(0.5)
    received.clear()
    t0 = time.perf_counter()
    for _ in range(N):
        publish()
    deadline = time.time() + 10
    while len(received) < N * 0.99 and time.time() < deadline:
        time.sleep(0.01)
    elapsed = time.perf_counter() - t0
    latency_us = np.array([now - stamp for now, stamp in received]) * 1e6
    return len(received) / elapsed, float(np.percentile(latency_us, 50)), float(np.percentile(latency_us, 99))


def bench_bus() -> tuple[float, float, float]:
    port = free_port()
    ideal = {hop: profile("ideal") for hop in ("rov", "tether", "satellite")}
    sim = Bus(SYSTEM, "simulation", ideal, listen=[f"tcp/127.0.0.1:{port}"])
    onboard = Bus(SYSTEM, "onboard", ideal, connect=[f"tcp/127.0.0.1:{port}"])
    received: list[tuple[float, float]] = []
    inbox = onboard.subscribe("simulation", "nav", maxlen=8)
    original_put = inbox.put

    def put(item: Received) -> None:
        received.append((time.time(), item.stamp_s))
        original_put(item)

    inbox.put = put  # type: ignore[method-assign]
    time.sleep(1.0)
    message = nav()
    result = measure(lambda: sim.publish("nav", message), received)
    sim.close()
    onboard.close()
    return result


def bench_raw() -> tuple[float, float, float]:
    port = free_port()
    a = open_session(zenoh_config(listen=[f"tcp/127.0.0.1:{port}"]), "raw a")
    b = open_session(zenoh_config(connect=[f"tcp/127.0.0.1:{port}"]), "raw b")
    received: list[tuple[float, float]] = []

    def on_sample(sample: zenoh.Sample) -> None:
        data = sample.payload.to_bytes()
        received.append((time.time(), float(np.frombuffer(data[-8:], "<f8")[0])))

    sub = b.declare_subscriber("abyss/bench/raw", on_sample)
    pub = a.declare_publisher("abyss/bench/raw")
    time.sleep(1.0)
    body = encode(nav(), 0, 0.0)  # the same bytes the bus sends, the send time appended
    result = measure(lambda: pub.put(body + np.float64(time.time()).tobytes()), received)
    sub.undeclare()
    pub.undeclare()
    a.close()
    b.close()
    return result


def bench_startup(runs: int = 3) -> list[float]:
    times = []
    for i in range(runs):
        out = Path("runs") / f"bench-startup-{i}"
        done = subprocess.run([sys.executable, "-m", "stations.cli", "up", "--duration", "1", "--port", "0",
                               "--out", str(out), "--system", f"bench{i}"], capture_output=True, text=True)
        m = re.search(r"all 4 stations up in ([0-9.]+) s", done.stdout)
        if m:
            times.append(float(m.group(1)))
    return times


if __name__ == "__main__":
    raw = bench_raw()
    bus = bench_bus()
    print(f"raw zenoh-python: {raw[0]:8.0f} msg/s, latency p50 {raw[1]:6.0f} us, p99 {raw[2]:7.0f} us")
    print(f"common/bus.py   : {bus[0]:8.0f} msg/s, latency p50 {bus[1]:6.0f} us, p99 {bus[2]:7.0f} us")
    print(f"bus / raw       : throughput {bus[0] / raw[0]:.2f}x, latency p50 {bus[1] / raw[1]:.2f}x, "
          f"p99 {bus[2] / raw[2]:.2f}x")
    startup = bench_startup()
    print(f"abyss up start-up to all four alive: {', '.join(f'{t:.2f}' for t in startup)} s")
