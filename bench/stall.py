"""Simulated time that cannot stand still, on the scenario that stood it still: `satellite-storm` at
`--time sim --speed max` N times (the vessel's relay towards shore blocked on the satellite's
full queue at 256 kbit/s), each run's verdict, its wall time and what its simulation log says of
a laggard that stood still (`Holdback`: named after 5 s, the run failed past 60 s); then the same
scenario twice in lockstep with one seed, `control.csv` and every message each station sent
`control.csv`, `panel.csv`, shore's scene and every message each station sent (where the run
kept its recording) compared byte for byte.

Run: .venv/bin/python bench/stall.py [--runs 20] [--parallel 2] [--scenario NAME]. Prints
figures; exits 1 if a run stood still, failed, or the lockstep pair differs."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from abyss.interface import keys
from abyss.recording.reader import read_file

ROOT = Path(__file__).resolve().parents[1]
STOOD = ("no further for", "simulated time stood still")  # timing.clock.Holdback's words


def scenario_run(files: list[Path], out: Path, *time_args: str, parallel: int = 1) -> str:
    """`abyss scenario run` of `files` into `out`: its last line."""
    command = [sys.executable, "-P", "-m", "abyss.cli", "scenario", "run", *map(str, files), *time_args]
    command += ["--parallel", str(parallel), "--report", str(out)]
    done = subprocess.run(command, capture_output=True, text=True, cwd=out.parent)
    return (done.stdout.strip().splitlines() or [done.stderr.strip()])[-1]


def sent(run: Path, station: str) -> dict[tuple[str, int], bytes]:
    """What `station` sent, by key (less the system's id, each run's own) and sequence number."""
    records = read_file(run / "record" / f"{station}.mcap").records
    return {(r.key.split("/", 2)[2], r.seq): r.payload for r in records if r.direction == "sent"}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--runs", type=int, default=20)
    parser.add_argument("--parallel", type=int, default=2)
    parser.add_argument("--scenario", default="satellite-storm")
    args = parser.parse_args()
    scenario = ROOT / "scenarios" / f"{args.scenario}.toml"
    bad = 0
    with tempfile.TemporaryDirectory(prefix="abyss-stall-") as tmp_dir:
        tmp = Path(tmp_dir)
        t0 = time.monotonic()
        print(f"{args.scenario} at --speed max, {args.runs} runs, {args.parallel} at once:", flush=True)
        if args.runs:
            last = scenario_run(
                [scenario] * args.runs, tmp / "max", "--time", "sim", "--speed", "max", parallel=args.parallel
            )
            print(f"  {last} ({time.monotonic() - t0:.0f} s)")
        for run in sorted((tmp / "max" / "runs").iterdir()) if args.runs else ():
            summary = json.loads((run / "summary.json").read_text())
            log = (run / "simulation.log").read_text()
            stood = [line for line in log.splitlines() if any(w in line for w in STOOD)]
            timing = summary.get("time", {})
            print(
                f"  {run.name}: {summary['verdict']}, {timing.get('sim_s', 0):.1f} s simulated at "
                f"x{timing.get('achieved_speed', 0) or 0:.2f}, limited by {timing.get('limited_by')}; "
                f"{len(stood)} laggards stood still" + (f": {stood[0]}" if stood else "")
            )
            bad += bool(stood) or summary["verdict"] != "done"
        print(f"{args.scenario} twice in lockstep, one seed:", flush=True)
        runs = []
        for name in ("a", "b"):
            print(f"  {name}: {scenario_run([scenario], tmp / name, '--time', 'lockstep')}", flush=True)
            runs.append(next((tmp / name / "runs").iterdir()))
        a, b = runs
        for name in ("control.csv", "panel.csv", "scene.msgpack"):  # the records, shore's scene
            same = (a / name).read_bytes() == (b / name).read_bytes()
            print(f"  {name}: {'byte-identical' if same else 'DIFFERS'} ({(a / name).stat().st_size} B)")
            bad += not same
        for station in keys.STATIONS if any((a / "record").glob("*.mcap")) else ():
            mine, theirs = sent(a, station), sent(b, station)
            same = bool(mine) and mine == theirs
            print(f"  {station}'s {len(mine)} messages sent: {'byte-identical' if same else 'DIFFER'}")
            bad += not same
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
