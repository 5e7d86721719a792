"""The scenario library on this machine: its wall time at --parallel 1 and 2 (the ratio is the
speed-up), and how many whole systems run at once before the simulation's real-time deadlines
slip (the nominal scenario N times at --parallel N, N = 1, 2, 3, ...: the share of deadlines met
and whether the missions still end), with the physics at real-time priority (the default) and on
the normal scheduler. With --times: the library (or --scenarios) on each time
source, real and simulated at each speed, its wall time as a ratio to real time's, each run's
achieved speed and what held it back, and whether every verdict is real time's.
Run: .venv/bin/python bench/scenarios.py [--max-systems N] [--skip-library]
     [--times real,2,4,max [--parallel N] [--scenarios NAME,...]]. Prints figures."""

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


def run(files: list[Path], parallel: int, out: Path, speed: str = "") -> tuple[float, str]:
    """The scenarios' wall time and the runner's last line; `speed`: on simulated time at it."""
    t0 = time.monotonic()
    command = [sys.executable, "-m", "abyss.cli", "scenario", "run", *map(str, files)]
    command += ["--parallel", str(parallel), "--report", str(out)]
    command += (
        ["--time", "lockstep"]
        if speed == "lockstep"
        else ["--time", "sim", "--speed", speed]
        if speed
        else []
    )
    done = subprocess.run(command, capture_output=True, text=True, cwd=ROOT)
    return time.monotonic() - t0, done.stdout.strip().splitlines()[-1] if done.stdout.strip() else done.stderr


def times(files: list[Path], speeds: list[str], parallel: int, tmp: Path) -> None:
    """The scenarios on each time source: wall time against real time's, speed, verdicts."""
    walls: dict[str, float] = {}
    words: dict[str, dict[str, str]] = {}
    for speed in speeds:
        sim = "" if speed == "real" else speed
        out = tmp / f"times-{speed}"
        print(
            f"{len(files)} scenarios at --parallel {parallel}, "
            f"{'real time' if not sim else sim if sim == 'lockstep' else f'--time sim --speed {sim}'} ...",
            flush=True,
        )
        walls[speed], verdict = run(files, parallel, out, sim)
        summaries = {
            p.parent.name.split("-", 1)[1]: json.loads(p.read_text())
            for p in sorted(out.glob("runs/*/summary.json"))
        }
        words[speed] = {name: s["verdict"] for name, s in summaries.items()}
        timing = [s.get("time", {}) for s in summaries.values()]
        achieved = [t["achieved_speed"] for t in timing if "achieved_speed" in t]
        limits = sorted({t["limited_by"] for t in timing if "limited_by" in t})
        print(
            f"  {walls[speed]:.0f} s ({walls[speed] / walls.get('real', walls[speed]):.2f}x real time's"
            f"{'' if 'real' in walls else ', no real-time run to compare'}): {verdict}"
            + (
                f"; achieved speed {min(achieved):.2f}-{max(achieved):.2f}, held back by {', '.join(limits)}"
                if achieved
                else ""
            ),
            flush=True,
        )
        if "real" in words and speed != "real":
            real = words["real"]
            differ = {n: (real.get(n), w) for n, w in words[speed].items() if real.get(n) != w}
            print(f"  verdicts {'as in real time' if not differ else f'differ from real time: {differ}'}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--max-systems", type=int, default=4)
    parser.add_argument("--skip-library", action="store_true")
    parser.add_argument("--times", metavar="real,X,...,max,lockstep", help="the time sources to compare")
    parser.add_argument("--parallel", type=int, default=1, help="with --times: systems at once")
    parser.add_argument("--scenarios", metavar="NAME,...", help="with --times: these, not the library")
    args = parser.parse_args()
    if args.times:
        chosen = args.scenarios.split(",") if args.scenarios else None
        files = [p for p in LIBRARY if chosen is None or p.stem in chosen]
        with tempfile.TemporaryDirectory() as tmp:
            times(files, args.times.split(","), args.parallel, Path(tmp))
        return
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
        normal = Path(tmp) / "nominal-normal-scheduler.toml"  # the same, physics without real-time priority
        text = nominal.read_text()
        assert "[config]" not in text, "nominal.toml has a [config] table: add the priority to it"
        normal.write_text(f'{text}\n[config]\n"simulation.realtime_priority" = 0\n')
        for n in range(1, args.max_systems + 1):
            worst = 1.0
            for scheduler, scenario in (("normal", normal), ("real-time", nominal)):
                out = Path(tmp) / f"systems-{n}-{scheduler}"
                wall_s, verdict = run([scenario] * n, n, out)
                summaries = [json.loads(p.read_text()) for p in sorted(out.glob("runs/*/summary.json"))]
                met = [s["simulation"]["deadlines_met"] for s in summaries if s.get("simulation")]
                loops = [
                    (f"{station}.{name}", loop["deadlines_met"])
                    for s in summaries
                    for station, st in s["stations"].items()
                    for name, loop in st.get("loops", {}).items()
                ]
                others = min((m for name, m in loops if name != "simulation.physics"), default=0)
                done = [s.get("mission_done_s") for s in summaries]
                schedulers = sorted({s["stations"]["simulation"].get("scheduler", "?") for s in summaries})
                print(
                    f"{n} systems at once, physics on {', '.join(schedulers)}: deadlines met "
                    f"{min(met, default=0):.1%} (worst) .. {max(met, default=0):.1%}; every other loop >= "
                    f"{others:.1%}; missions done at {[round(d) if d else None for d in done]} s; wall "
                    f"{wall_s:.0f} s",
                    flush=True,
                )
                worst = min(met, default=0)
            if worst < SLIPPED:
                print(f"deadlines slip (< {SLIPPED:.0%}) from {n} whole systems at once on this machine")
                break


if __name__ == "__main__":
    main()
