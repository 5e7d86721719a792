"""End to end through the four real processes: `abyss up` with the default profiles, and
each hop's receive latency (receiver's clock minus the sender's stamp, one machine, one
clock) against that hop's floor (configured delay + serialisation of the message).
Run: .venv/bin/python bench/e2e.py [SECONDS] (default 90: how long the system stays up).
Prints figures; asserts nothing."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from abyss.config import Config
from abyss.interface import keys
from abyss.linkemu.link import HEADER_BYTES

# the chain of keys that carries the vehicle's state from simulation to shore
CHAIN = (("simulation", "nav"), ("onboard", "telemetry"), ("vessel", "telemetry"))
MESSAGE_BYTES = {"nav": 330, "telemetry": 330}  # approximate encoded sizes


def main(seconds: float) -> None:
    system = "bench-e2e"
    out = Path("runs") / system
    subprocess.run(
        [
            sys.executable,
            "-m",
            "abyss.cli",
            "up",
            "--keep-running",
            "--duration",
            str(seconds),
            "--port",
            "0",
            "--out",
            str(out),
            "--system",
            system,
        ],
        check=True,
        capture_output=True,
    )
    summary = json.loads((out / "summary.json").read_text())
    profiles = Config().links.profiles()
    total_p50_ms = total_floor_ms = 0.0
    for station, topic in CHAIN:
        spec = keys.spec(station, topic)
        p = profiles[spec.hop]
        size = MESSAGE_BYTES[topic] + HEADER_BYTES[p.transport]
        floor_ms = (p.delay_s + (size * 8 / p.rate_bps if p.rate_bps != float("inf") else 0.0)) * 1e3
        latency = summary["stations"][spec.to]["latency_ms"][spec.key(system)]
        total_p50_ms += latency["latency_p50_ms"]
        total_floor_ms += floor_ms
        print(
            f"{spec.hop:<9} {station}/{topic:<10} p50 {latency['latency_p50_ms']:8.2f} ms  "
            f"p99 {latency['latency_p99_ms']:8.2f} ms  floor {floor_ms:7.2f} ms  "
            f"p50/floor {latency['latency_p50_ms'] / floor_ms if floor_ms else float('nan'):.3f}"
        )
    print(
        f"simulation -> onshore, sum of hop p50 {total_p50_ms:.2f} ms against the floor "
        f"{total_floor_ms:.2f} ms: ratio {total_p50_ms / total_floor_ms:.3f} (relay waits excluded: "
        f"onboard and vessel forward at their own periods)"
    )


if __name__ == "__main__":
    main(float(sys.argv[1]) if len(sys.argv) > 1 else 90.0)
