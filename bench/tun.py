"""The TUN shaper's cost: what one forwarder (one Python thread, `linkemu/tun.py`) carries and
how much delay it adds, against the plain veth pair in the same run.

A throw-away lab (`launch.lab.Lab`); the rov hop, simulation -> onboard, either plain or shaped
by `abyss link shape rov --profile ideal` (no rate, delay or loss: the forwarder's own cost).
- delay: 400 pings at 10 ms intervals, RTT p50/p99 (one direction shaped, the reply plain);
- capacity: a UDP flow offered at rising rates for 2 s each, 1500 B and 200 B IP packets:
  delivered Mbit/s and packets/s, what was lost, and the shaper's CPU time per packet (the
  Python sender tops out near 7 kpps here: the plain veth's figure is that floor, and 1e6 / the
  CPU time per packet is what one core of forwarder could carry).
As root, with /dev/net/tun; about a minute. Run: .venv/bin/python bench/tun.py [--seconds S]"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from abyss.launch.lab import Lab, usable

ROOT = Path(__file__).resolve().parents[1]
FLOW = [sys.executable, str(ROOT / "tests" / "e2e" / "udpflow.py")]
PORT = 5301
RATES_MBPS = {1500: (50, 100, 200, 400), 200: (5, 10, 20, 40)}  # per IP packet size
CLOCK_TICKS = os.sysconf("SC_CLK_TCK")


def rtts_ms(lab: Lab, count: int = 400) -> np.ndarray:
    done = subprocess.run(
        [
            *lab.prefix("simulation"),
            "ping",
            "-n",
            "-c",
            str(count),
            "-i",
            "0.01",
            lab.address("onboard", "rov"),
        ],
        capture_output=True,
        text=True,
        check=True,
    )
    return np.array([float(m) for m in re.findall(r"time=([\d.]+) ms", done.stdout)])


def flow(lab: Lab, rate_mbps: float, ip_bytes: int, seconds: float) -> dict[str, float]:
    """A UDP flow across the rov hop: what was sent and what arrived."""
    address = lab.address("onboard", "rov")
    receiver = subprocess.Popen(
        [*lab.prefix("onboard"), *FLOW, "receive", address, str(PORT), str(seconds)],
        stdout=subprocess.PIPE,
        text=True,
    )
    time.sleep(0.3)  # bound before the first datagram
    sent = json.loads(
        subprocess.run(
            [
                *lab.prefix("simulation"),
                *FLOW,
                "send",
                address,
                str(PORT),
                str(rate_mbps * 1e6),
                str(seconds),
                str(ip_bytes - 28),
            ],
            capture_output=True,
            text=True,
            check=True,
        ).stdout
    )
    got = json.loads(receiver.communicate(timeout=60)[0])
    span_s = max(got["last_s"] - got["first_s"], 1e-9)
    return {
        "sent": sent["sent"],
        "received": got["packets"],
        "mbps": got["ip_bytes"] * 8 / span_s / 1e6,
        "pps": got["packets"] / span_s,
    }


def cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLOCK_TICKS  # utime + stime


class Shaper:
    """`abyss link shape rov --profile ideal` on simulation's side."""

    def __init__(self, lab: Lab, log: Path) -> None:
        self.log = log
        with log.open("w") as out:
            self.process = subprocess.Popen(
                lab.shape("simulation", "rov", "ideal", "--every", "3600"),
                stdout=out,
                stderr=subprocess.STDOUT,
                text=True,
            )
        deadline = time.monotonic() + 30.0
        while "abyss: shaping packets" not in log.read_text():
            if self.process.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"abyss link shape did not start:\n{log.read_text()}")
            time.sleep(0.05)

    def cpu_s(self) -> float:
        """The shaper's CPU time: `ip netns exec` execs it, so the pid is the shaper's own."""
        return cpu_s(self.process.pid)

    def stop(self) -> dict[str, float]:
        self.process.terminate()
        self.process.wait(timeout=10)
        stats: dict[str, float] = json.loads(self.log.read_text().strip().splitlines()[-1])
        return stats


def measure(lab: Lab, shaper: Shaper | None, seconds: float) -> dict[str, Any]:
    rtt = rtts_ms(lab)
    print(f"  ping: RTT p50 {np.percentile(rtt, 50):.3f} ms, p99 {np.percentile(rtt, 99):.3f} ms", flush=True)
    flows = []
    for ip_bytes, rates in RATES_MBPS.items():
        for rate in rates:
            before = shaper.cpu_s() if shaper else 0.0
            f = flow(lab, rate, ip_bytes, seconds)
            spent_s = shaper.cpu_s() - before if shaper else 0.0
            f["cpu_us_per_packet"] = spent_s / max(f["received"], 1) * 1e6
            f.update(ip_bytes=ip_bytes, offered_mbps=rate)
            lost = 1.0 - f["received"] / max(f["sent"], 1)
            print(
                f"  {ip_bytes:>4} B at {rate:>3} Mbit/s offered: {f['mbps']:6.1f} Mbit/s, "
                f"{f['pps'] / 1e3:6.1f} kpps delivered, {lost:6.1%} lost"
                + (f", shaper {f['cpu_us_per_packet']:.1f} us CPU/packet" if shaper else ""),
                flush=True,
            )
            flows.append(f)
    return {
        "rtt_p50_ms": float(np.percentile(rtt, 50)),
        "rtt_p99_ms": float(np.percentile(rtt, 99)),
        "flows": flows,
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=2.0, help="each flow's length")
    parser.add_argument("--out", type=Path, default=Path("bench/results/tun"))
    args = parser.parse_args()
    if reason := usable():
        print(f"bench/tun.py: {reason}", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    lab = Lab("bench-tun").make(echo=lambda line: None)
    try:
        print("plain veth:", flush=True)
        plain = measure(lab, None, args.seconds)
        print("through the TUN shaper (profile ideal):", flush=True)
        shaper = Shaper(lab, args.out / "shape.log")
        try:
            shaped = measure(lab, shaper, args.seconds)
        finally:
            stats = shaper.stop()
    finally:
        lab.remove()
    print(
        f"added RTT: p50 {shaped['rtt_p50_ms'] - plain['rtt_p50_ms']:+.3f} ms, "
        f"p99 {shaped['rtt_p99_ms'] - plain['rtt_p99_ms']:+.3f} ms"
    )
    for ip_bytes in RATES_MBPS:
        best = {
            name: max(f["mbps"] for f in run["flows"] if f["ip_bytes"] == ip_bytes)
            for name, run in (("plain", plain), ("shaped", shaped))
        }
        print(
            f"{ip_bytes} B packets: the shaper delivered up to {best['shaped']:.1f} Mbit/s, "
            f"{best['shaped'] / best['plain']:.2f}x the plain veth's {best['plain']:.1f} in the same run"
        )
    print(f"shaper counters: {json.dumps({k: stats[k] for k in sorted(stats) if not k.startswith('delay')})}")
    results = {"plain": plain, "shaped": shaped, "shaper": stats}
    (args.out / "tun.json").write_text(json.dumps(results, indent=1))
    print(f"written: {args.out / 'tun.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
