"""`abyss export mcap`, measured on a recorded run: the export's time per minute of run and as a
share of the run's duration (the best of a few exports), and the file's size per minute. Without
a run directory it records one first: the default mission (`abyss up --record all`).
Run: .venv/bin/python bench/export.py [RUN_DIR] [--repeats N]. Prints figures; asserts nothing."""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

from abyss.ros2.mcap import export_mcap

ROOT = Path(__file__).resolve().parents[1]


def record_run(out: Path) -> None:
    print("recording the default mission (abyss up --record all) ...", flush=True)
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "abyss.cli",
            "up",
            "--port",
            "0",
            "--viewer",
            "none",
            "--record",
            "all",
            "--duration",
            "120",
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
        cwd=ROOT,
    )
    if done.returncode != 0:
        raise SystemExit("abyss up failed:\n" + done.stdout + done.stderr)


def bench(run_dir: Path, repeats: int) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        summaries = [export_mcap(run_dir, Path(tmp) / "run.mcap") for _ in range(repeats)]
    best = min(summaries, key=lambda s: s["export_s"])
    minutes = best["run_s"] / 60
    print(f"run: {best['run_s']:.0f} s, {best['messages']} messages on {len(best['topics'])} topics")
    print(f"export time          : {best['export_s']:6.2f} s (best of {repeats})")
    print(f"export per run minute: {best['export_s'] / minutes:6.2f} s")
    print(f"export / run duration: {best['export_s'] / best['run_s']:6.1%}")
    print(f"file size per minute : {best['bytes'] / minutes / 1e6:6.1f} MB")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument(
        "run_dir", type=Path, nargs="?", metavar="RUN_DIR", help="a recorded run (default: record one)"
    )
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    if args.run_dir is not None:
        bench(args.run_dir, args.repeats)
        return
    with tempfile.TemporaryDirectory() as tmp:
        record_run(Path(tmp) / "run")
        bench(Path(tmp) / "run", args.repeats)


if __name__ == "__main__":
    main()
