"""Campaigns on Ray, on this machine: what Ray itself costs, and what a campaign's throughput is.

1. Ray's cost: the same runs (one scenario, N seeds, lockstep) through `abyss campaign run` (a
   local Ray started by the command) and `abyss scenario run --parallel auto` (a process pool):
   the wall time ratio (goal <= 1.05) and the CPU share of the machine Ray's own processes took
   (gcs_server, raylet, its agents and idle workers: every process of the run that is neither the
   driver, a task's worker running a run, nor a system's).
2. Throughput: a campaign of library scenarios on each time source, in simulated seconds per
   wall second, and each run's cost (core-seconds per simulated second).
3. On paper: the runs per hour that N nodes of C cores give, from the measured per-run costs.

Run: .venv/bin/python bench/campaign.py [--runs 6] [--sources lockstep,real]
     [--scenarios nominal,tether-outage] [--seeds 2] [--skip-ray] [--skip-throughput]"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TICK_S = os.sysconf("SC_CLK_TCK")
RAY_OWN = re.compile(
    r"gcs_server|raylet|dashboard|log_monitor|monitor\.py|runtime_env|agent"
)  # Ray's daemons
RAY_WORKER = re.compile(
    r"^ray::"
)  # a task's worker: the runner's work, as scenario run's own process does it


class CpuWatch:
    """Every process on the machine sampled twice a second: its last CPU seconds and command."""

    def __init__(self) -> None:
        self.cpu_s: dict[int, float] = {}
        self.command: dict[int, str] = {}
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self.stop.wait(0.5):
            for entry in os.scandir("/proc"):
                if not entry.name.isdigit():
                    continue
                pid = int(entry.name)
                try:
                    stat = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
                    cmd = (
                        Path(f"/proc/{pid}/cmdline")
                        .read_bytes()
                        .replace(b"\0", b" ")
                        .decode(errors="replace")
                    )
                except OSError:
                    continue
                self.cpu_s[pid] = (int(stat[11]) + int(stat[12])) / TICK_S
                self.command[pid] = cmd

    def finish(self) -> dict[int, float]:
        self.stop.set()
        self.thread.join()
        return self.cpu_s


def scenario_file(tmp: Path, duration_s: float) -> Path:
    """The default mission for `duration_s`, judged on nothing the bench needs (stations up)."""
    path = tmp / "bench-mission.toml"
    path.write_text(
        'name = "bench-mission"\nuse = "interface"\n'
        f"duration_s = {duration_s}\nstop_when_done = false\n\n"
        '[[assert]]\nkind = "stations"\nmax_restarts = 0\n'
    )
    return path


def timed(command: list[str], cwd: Path) -> tuple[float, dict[int, float], dict[int, str], str]:
    before = set(int(p) for p in os.listdir("/proc") if p.isdigit())
    watch = CpuWatch()
    t0 = time.monotonic()
    done = subprocess.run(command, cwd=cwd, capture_output=True, text=True)
    wall_s = time.monotonic() - t0
    cpu = {pid: s for pid, s in watch.finish().items() if pid not in before}
    return wall_s, cpu, watch.command, done.stdout + done.stderr


def ray_cost(runs: int, duration_s: float, tmp: Path) -> None:
    scenario = scenario_file(tmp, duration_s)
    seeded = []
    for seed in range(runs):
        path = tmp / f"seed-{seed}.toml"
        path.write_text(
            scenario.read_text().replace('name = "bench-mission"', f'name = "bench-mission-{seed}"')
            + f"\n[config]\nseed = {seed}\n"
        )
        seeded.append(path)
    (tmp / "c.toml").write_text(
        f'name = "bench"\nscenarios = ["{scenario.name}"]\nseeds = {runs}\ntime = "lockstep"\n'
    )
    abyss = [sys.executable, "-P", "-m", "abyss.cli"]
    print(f"Ray's cost: {runs} runs of {duration_s:g} simulated s in lockstep, each way ...", flush=True)
    pool_wall, pool_cpu, _, pool_out = timed(
        [
            *abyss,
            "scenario",
            "run",
            *map(str, seeded),
            "--parallel",
            "auto",
            "--time",
            "lockstep",
            "--report",
            str(tmp / "pool"),
        ],
        tmp,
    )
    ray_wall, ray_cpu, commands, ray_out = timed(
        [*abyss, "campaign", "run", "c.toml", "--out", str(tmp / "ray")], tmp
    )
    own = sum(s for pid, s in ray_cpu.items() if RAY_OWN.search(commands.get(pid, "")))
    workers = sum(s for pid, s in ray_cpu.items() if RAY_WORKER.search(commands.get(pid, "")))
    cores = len(os.sched_getaffinity(0))
    print(
        f"  scenario run --parallel auto: {pool_wall:.1f} s wall, {sum(pool_cpu.values()):.1f} CPU s "
        f"({pool_out.strip().splitlines()[-1]})"
    )
    print(f"  campaign run (local Ray):     {ray_wall:.1f} s wall, {sum(ray_cpu.values()):.1f} CPU s")
    print(f"  wall ratio campaign / pool: {ray_wall / pool_wall:.3f} (goal <= 1.05)")
    print(
        f"  Ray's own processes: {own:.1f} CPU s = {own / (ray_wall * cores):.1%} of the machine's "
        f"{cores} cores over the campaign"
    )
    print(
        f"  Ray's task workers (the runner's work, and Ray's in them): {workers:.1f} CPU s = "
        f"{workers / (ray_wall * cores):.1%}"
    )
    if "runs done" not in ray_out:
        print(ray_out[-3000:])


def throughput(names: list[str], seeds: int, sources: list[str], tmp: Path) -> list[dict[str, float]]:
    costs = []
    for source in sources:
        out = tmp / f"tp-{source}"
        files = ", ".join(f'"{ROOT / "scenarios" / name}.toml"' for name in names)
        (tmp / f"tp-{source}.toml").write_text(
            f'name = "tp-{source}"\nscenarios = [{files}]\nseeds = {seeds}\ntime = "{source}"\n'
        )
        print(f"throughput: {', '.join(names)} x {seeds} seeds on {source} time ...", flush=True)
        t0 = time.monotonic()
        subprocess.run(
            [
                sys.executable,
                "-P",
                "-m",
                "abyss.cli",
                "campaign",
                "run",
                f"tp-{source}.toml",
                "--out",
                str(out),
            ],
            cwd=tmp,
            capture_output=True,
            text=True,
        )
        wall_s = time.monotonic() - t0
        rows = [json.loads(line) for line in (out / "results.jsonl").read_text().splitlines() if line.strip()]
        sim_s = sum(r["sim_s"] for r in rows)
        core_s = sum(r["core_s"] for r in rows)
        passed = sum(r["passed"] for r in rows)
        print(
            f"  {source}: {len(rows)} runs ({passed} passed), {sim_s:.0f} simulated s in {wall_s:.0f} wall s "
            f"= {sim_s / wall_s:.2f} simulated s per wall s; {core_s / sim_s:.2f} core-s per simulated s"
        )
        costs.append(
            {
                "source": source,
                "wall_per_run_s": sum(r["wall_s"] for r in rows) / max(len(rows), 1),  # each run's own
                "core_s_per_run": core_s / max(len(rows), 1),
                "sim_s_per_run": sim_s / max(len(rows), 1),
            }
        )
    return costs


def on_paper(costs: list[dict[str, float]]) -> None:
    """Runs per hour on N nodes of C cores: each node runs floor(0.8 C / cores per system) systems
    at once (the headroom --parallel auto keeps), each run taking its own measured wall time (from
    its start to its end, not the campaign's wall time shared among the runs beside it)."""
    print("on paper, runs per hour (from the measured per-run costs, 80 % of each node's cores):")
    for cost in costs:
        per_system = cost["core_s_per_run"] / max(cost["wall_per_run_s"], 1e-9)
        for cores in (16, 64):
            at_once = max(1, math.floor(0.8 * cores / max(per_system, 1e-9)))
            hourly = at_once * 3600 / cost["wall_per_run_s"]
            line = ", ".join(f"{n} nodes: {n * hourly:,.0f}" for n in (1, 10, 100))
            print(f"  {cost['source']}, {cores}-core nodes ({at_once} systems each): {line}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=6)
    parser.add_argument("--duration", type=float, default=15.0, help="simulated seconds per run of part 1")
    parser.add_argument("--sources", default="lockstep,real")
    parser.add_argument("--scenarios", default="nominal,tether-outage")
    parser.add_argument("--seeds", type=int, default=2)
    parser.add_argument("--skip-ray", action="store_true")
    parser.add_argument("--skip-throughput", action="store_true")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="abyss-bench-campaign-") as scratch:
        tmp = Path(scratch)
        if not args.skip_ray:
            ray_cost(args.runs, args.duration, tmp)
        if not args.skip_throughput:
            on_paper(throughput(args.scenarios.split(","), args.seeds, args.sources.split(","), tmp))


if __name__ == "__main__":
    main()
