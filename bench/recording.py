"""The bus recording's cost on the live system (`abyss up`, default mission, default links), each
level against the same run with `--record none` (the peer), in the same session:
- the whole run's CPU seconds (supervisor and stations, from the children's rusage), its ratio to
  the run without recording, and the recorders' own share of it: their writer threads' CPU time
  (each station's status) plus what queuing costs the publishing and receiving threads (measured
  here per message, times the messages recorded);
- the recording's bytes per minute of run, per level.
Run: .venv/bin/python bench/recording.py [--seconds S] [--repeat N]. Prints figures; asserts nothing."""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from abyss.interface import keys
from abyss.recording.store import RECORD_DIR, Caps, Recorder

ROOT = Path(__file__).resolve().parents[1]
LEVELS = ("none", "control", "all")


def children_cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def run(level: str, seconds: float, out: Path) -> tuple[float, float, float, int]:
    """(CPU seconds per second of run, recording bytes per minute, writer threads' CPU seconds,
    messages recorded) of one run of `seconds`."""
    c0, t0 = children_cpu_s(), time.monotonic()
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "abyss.cli",
            "up",
            "--port",
            "0",
            "--keep-running",
            "--duration",
            str(seconds),
            "--viewer",
            "none",
            "--record",
            level,
            "--out",
            str(out),
            "--system",
            f"bench-{level}",
        ],
        capture_output=True,
        text=True,
        cwd=ROOT,
    )
    if done.returncode != 0:
        raise SystemExit(f"abyss up failed:\n{done.stdout}{done.stderr}")
    wall_s, cpu = time.monotonic() - t0, children_cpu_s() - c0
    statuses = [json.loads((out / f"{name}.json").read_text()).get("recording", {}) for name in keys.STATIONS]
    writer_s = sum(s.get("writer_cpu_s", 0.0) for s in statuses)
    recorded = sum(sum(s.get("recorded", {}).values()) for s in statuses)
    size = sum(p.stat().st_size for p in (out / RECORD_DIR).glob("*.mcap"))
    return cpu / wall_s, size / wall_s * 60.0, writer_s / wall_s, recorded


def queue_cost_s(tmp: Path, count: int = 20_000) -> float:
    """CPU seconds one `Recorder.add` costs the calling thread (a token bucket and a queue put)."""
    recorder = Recorder(tmp / "q.mcap", "onboard", "bench", "all", Caps(max_hz=1e9, bulk_hz=1e9))
    payload = bytes(200)
    t0 = time.thread_time()
    for _ in range(count):
        recorder.add("sent", "abyss/bench/onboard/telemetry", payload)
    per_add_s = (time.thread_time() - t0) / count
    recorder.close()
    return per_add_s


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=40.0, help="seconds per run")
    parser.add_argument("--repeat", type=int, default=2, help="runs per level, interleaved")
    args = parser.parse_args()
    figures: dict[str, list[tuple[float, float, float, int]]] = {level: [] for level in LEVELS}
    with tempfile.TemporaryDirectory() as tmp:
        per_add_s = queue_cost_s(Path(tmp))
        for i in range(args.repeat):
            for level in LEVELS:
                print(
                    f"run {i + 1}/{args.repeat}: abyss up --record {level} for {args.seconds:.0f} s ...",
                    flush=True,
                )
                figures[level].append(run(level, args.seconds, Path(tmp) / f"{level}-{i}"))
    bare = statistics.median(f[0] for f in figures["none"])
    print(f"queuing one message costs the caller {per_add_s * 1e6:.1f} us of CPU")
    print(
        f"{'level':8} {'run CPU s/s':>12} {'vs none':>8} {'recorder CPU s/s':>17} {'share':>6} "
        f"{'msgs/s':>7} {'MB/min':>7}"
    )
    for level in LEVELS:
        cpu = statistics.median(f[0] for f in figures[level])
        recorded_per_s = statistics.median(f[3] for f in figures[level]) / args.seconds
        recorder = statistics.median(f[2] for f in figures[level]) + recorded_per_s * per_add_s
        print(
            f"{level:8} {cpu:12.3f} {cpu / bare:7.2f}x {recorder:17.4f} {recorder / cpu:6.1%} "
            f"{recorded_per_s:7.0f} {statistics.median(f[1] for f in figures[level]) / 1e6:7.1f}"
        )


if __name__ == "__main__":
    main()
