"""How long each station takes to stop after SIGINT (its bound is 5 s), idle and with every
sender blocked on a full satellite link (the `outage` profile all run long: reliable messages
pile up until the link's queue is full), over N whole systems each (`abyss up --duration S`, the
station's own `stop_s` from its status). Prints p50 and max per station and condition, and each
as a share of the bound.
Run: .venv/bin/python bench/stop.py [--runs 20] [--duration 8]."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
BOUND_S = 5.0
CONDITIONS = {"idle": [], "satellite saturated": ["--profile", "satellite=outage"]}


def stop_times(extra: list[str], runs: int, duration_s: float, out: Path) -> dict[str, list[float]]:
    times: dict[str, list[float]] = {}
    for i in range(runs):
        run_dir = out / f"run-{i}"
        subprocess.run(
            [
                sys.executable,
                "-P",
                "-m",
                "abyss.cli",
                "up",
                "--port",
                "0",
                "--viewer",
                "none",
                "--keep-running",
                "--duration",
                f"{duration_s:g}",
                "--out",
                str(run_dir),
                *extra,
            ],
            capture_output=True,
            cwd=out,
            check=False,
        )
        summary = json.loads((run_dir / "summary.json").read_text())
        for name, station in summary["stations"].items():
            times.setdefault(name, []).append(station["stop_s"])
        print(
            f"  run {i + 1}/{runs}: "
            + ", ".join(f"{n} {s['stop_s']:.2f} s" for n, s in summary["stations"].items()),
            flush=True,
        )
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--runs", type=int, default=20)
    parser.add_argument("--duration", type=float, default=8.0)
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for condition, extra in CONDITIONS.items():
            print(f"{condition}: {args.runs} systems of {args.duration:g} s ...", flush=True)
            out = Path(tmp) / condition.replace(" ", "-")
            out.mkdir()
            for name, times in stop_times(extra, args.runs, args.duration, out).items():
                p50, worst = float(np.median(times)), max(times)
                rows.append(
                    f"| {name} | {condition} | {len(times)} | {p50:.3f} | {worst:.3f} | "
                    f"{worst / BOUND_S:.1%} |"
                )
    print("\n| station | condition | stops | p50 s | max s | max / 5 s bound |")
    print("| --- | --- | --- | --- | --- | --- |")
    print("\n".join(rows))


if __name__ == "__main__":
    main()
