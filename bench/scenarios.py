"""The scenario library on this machine: its wall time at --parallel 1 and 2 (the ratio is the
speed-up), and how many whole systems run at once before the simulation's real-time deadlines
slip (the nominal scenario N times at --parallel N, N = 1, 2, 3, ...: the share of deadlines met
and whether the missions still end).
Run: .venv/bin/python bench/scenarios.py [--max-systems N] [--skip-library]. Prints figures."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LIBRARY = [p for p in sorted((ROOT / "scenarios").glob("*.toml")) if p.stem != "external-onboard"]
SLIPPED = 0.95  # a simulation that keeps fewer of its deadlines than this has slipped


def run(files: list[Path], parallel: int, out: Path) -> tuple[float, str]:
    t0 = time.monotonic()
    command = [sys.executable, "-m", "abyss.cli", "scenario", "run", *map(str, files)]
    command += ["--parallel", str(parallel), "--report", str(out)]
    done = subprocess.run(command, capture_output=True, text=True, cwd=ROOT)
    return time.monotonic() - t0, done.stdout.strip().splitlines()[-1] if done.stdout.strip() else done.stderr


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--max-systems", type=int, default=4)
    parser.add_argument("--skip-library", action="store_true")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        if not args.skip_library:
            walls = {}
            for parallel in (1, 2):
                print(f"library ({len(LIBRARY)} scenarios) at --parallel {parallel} ...", flush=True)
                walls[parallel], verdict = run(LIBRARY, parallel, Path(tmp) / f"library-{parallel}")
                print(f"  {walls[parallel]:.0f} s: {verdict}", flush=True)
            print(
                f"library wall time: --parallel 1 {walls[1]:.0f} s, --parallel 2 {walls[2]:.0f} s "
                f"({walls[1] / walls[2]:.2f}x faster)"
            )
        nominal = ROOT / "scenarios" / "nominal.toml"
        for n in range(1, args.max_systems + 1):
            out = Path(tmp) / f"systems-{n}"
            wall_s, verdict = run([nominal] * n, n, out)
            summaries = [json.loads(p.read_text()) for p in sorted(out.glob("runs/*/summary.json"))]
            met = [s["simulation"]["deadlines_met"] for s in summaries if s.get("simulation")]
            done = [s.get("mission_done_s") for s in summaries]
            print(
                f"{n} systems at once: deadlines met {min(met, default=0):.1%} (worst) .. "
                f"{max(met, default=0):.1%}; missions done at {[round(d) if d else None for d in done]} s; "
                f"wall {wall_s:.0f} s",
                flush=True,
            )
            if min(met, default=0) < SLIPPED:
                print(f"deadlines slip (< {SLIPPED:.0%}) from {n} whole systems at once on this machine")
                break


if __name__ == "__main__":
    main()
