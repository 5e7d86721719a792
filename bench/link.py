"""Link emulator figures: timing accuracy, rate accuracy, end-to-end latency against its floor.

Run: .venv/bin/python bench/link.py. Prints figures; asserts nothing."""

from __future__ import annotations

import threading
import time

import numpy as np

from abyss.config.linkprofile import profile
from abyss.linkemu.runner import LinkRunner


def timing_accuracy() -> None:
    """|actual - scheduled| delivery time on the wall clock, tether profile, 500 msg/s."""
    runner = LinkRunner(
        "bench", profile("tether", {"transport": "udp"}), lambda *_: None, np.random.default_rng(1)
    )
    for _ in range(3000):
        runner.send(bytes(200), block=False)
        time.sleep(0.002)
    time.sleep(0.5)
    stats = runner.snapshot()  # late = actual - scheduled >= 0: the runner never delivers early
    runner.close()
    print(
        f"timing accuracy (tether, 500 msg/s, {len(runner.late_s)} deliveries): "
        f"actual - scheduled p50 {stats['late_p50_us']:.0f} us, p99 {stats['late_p99_us']:.0f} us"
    )


def rate_accuracy(rate: str, seconds: float = 3.0, size: int = 1400) -> None:
    """A saturating flow (BLOCK when the queue is full): delivered wire rate / configured."""
    delivered: list[float] = []
    lock = threading.Lock()

    def deliver(_tag: object, payload: bytes) -> None:
        with lock:
            delivered.append(time.monotonic())

    p = profile("ideal", {"rate": rate, "transport": "udp", "queue_limit": "100"})
    runner = LinkRunner("bench", p, deliver, np.random.default_rng(2))
    t0 = time.monotonic()
    while time.monotonic() - t0 < seconds:
        runner.send(bytes(size), block=True)
    runner.close(drain_s=1.0)
    times = np.array(delivered)
    window = times[(times > t0 + 0.5)]  # after the queue has filled
    wire_bits = (size + 28) * 8 * (len(window) - 1)
    achieved = wire_bits / (window[-1] - window[0])
    print(
        f"rate accuracy at {rate:>7}: {achieved / 1e6:8.3f} Mbit/s on the wire, "
        f"ratio to configured {achieved / p.rate_bps:.3f}"
    )


def end_to_end_floor(n: int = 100) -> None:
    """onboard -> vessel -> onshore (tether then satellite, no load, no loss), one message per
    100 ms: latency against the floor (configured delays + serialisation)."""
    tether = profile("tether", {"jitter": "0ms"})
    satellite = profile("satellite", {"jitter": "0ms", "loss": "0%", "corrupt": "0%"})
    size = 300
    arrivals: dict[int, float] = {}
    rx = LinkRunner(
        "satellite",
        satellite,
        lambda tag, _p: arrivals.__setitem__(tag, time.monotonic()),
        np.random.default_rng(3),
    )
    tx = LinkRunner(
        "tether", tether, lambda tag, p: rx.send(p, block=True, tag=tag), np.random.default_rng(4)
    )
    sent: dict[int, float] = {}
    for i in range(n):
        sent[i] = time.monotonic()
        tx.send(bytes(size), block=True, tag=i)
        time.sleep(0.1)
    time.sleep(1.0)
    tx.close()
    rx.close()
    floor_s = (
        tether.delay_s
        + satellite.delay_s
        + (size + 40) * 8 / tether.rate_bps
        + (size + 40) * 8 / satellite.rate_bps
    )
    latency = np.array([arrivals[i] - sent[i] for i in sent if i in arrivals])
    print(
        f"end to end tether+satellite ({len(latency)} messages): p50 {np.median(latency) * 1e3:.2f} ms, "
        f"floor {floor_s * 1e3:.2f} ms, ratio {np.median(latency) / floor_s:.4f}"
    )


if __name__ == "__main__":
    timing_accuracy()
    for r in ("1mbit", "20mbit", "100mbit"):
        rate_accuracy(r)
    end_to_end_floor()
