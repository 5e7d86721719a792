"""The operator's viewer, measured on the live system (`abyss up`, default mission, default
links), against the same run with no viewer (the peer):
- the onshore station's CPU share (CPU seconds per wall second of its process) while logging;
- the recording's size per minute.
Run: .venv/bin/python bench/viewer.py [--seconds S]. Prints figures; asserts nothing."""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from abyss.launch.state import wait_for_state

ROOT = Path(__file__).resolve().parents[1]
TICKS_PER_S = os.sysconf("SC_CLK_TCK")


def cpu_s(pid: int) -> float:
    """User + system CPU time of a process [s]."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICKS_PER_S


def run(viewer: str, seconds: float, out: Path) -> tuple[float, float]:
    """(onshore CPU share, recording bytes per minute) of one run."""
    process = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "abyss.cli",
            "up",
            "--port",
            "0",
            "--keep-running",
            "--duration",
            str(seconds + 10),
            "--viewer",
            viewer,
            "--out",
            str(out),
            "--system",
            f"bench-{viewer}",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        cwd=ROOT,
    )
    lines: list[str] = []
    threading.Thread(target=lambda: lines.extend(process.stdout or ()), daemon=True).start()
    state = wait_for_state(out, lambda s: s.phase == "up", 120.0, lambda: process.poll() is None)
    pid = state.stations["onshore"].pid if state else None
    if pid is None:
        raise SystemExit("abyss up ended early:\n" + "".join(lines))
    time.sleep(5.0)  # past start-up
    t0, c0 = time.monotonic(), cpu_s(pid)
    time.sleep(seconds)
    share = (cpu_s(pid) - c0) / (time.monotonic() - t0)
    process.wait()
    recording = out / "onshore.rrd"
    size = recording.stat().st_size if recording.exists() else 0
    return share, size / (seconds + 15) * 60  # the recording spans the whole run


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=40.0, help="measured seconds per run")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        results = {}
        for viewer in ("none", "save"):
            print(f"running abyss up --viewer {viewer} for {args.seconds + 15:.0f} s ...", flush=True)
            results[viewer] = run(viewer, args.seconds, Path(tmp) / viewer)
    (bare, _), (logging_share, per_minute) = results["none"], results["save"]
    print(f"onshore CPU share without a viewer : {bare:6.1%} of one core")
    print(
        f"onshore CPU share logging to rerun : {logging_share:6.1%} of one core "
        f"({logging_share / max(bare, 1e-9):.1f}x the station without it)"
    )
    print(f"recording size                     : {per_minute / 1e6:6.1f} MB per minute")


if __name__ == "__main__":
    main()
