"""The cost of a simulated second: the default mission (`abyss up`, as a user runs it, rerun's
recording saved) on each time source, the CPU each station spent per simulated second from its
session's opening (its sensor processes included: the summary's `cpu_s`), their total, the whole
run's process tree's (the launcher, imports and start-up too: what a campaign pays per run), and
the speed achieved; alone and at two systems at once. With --baseline REV, the same runs of that
revision (`git archive REV`) in the same sitting, and the ratios, so that a change is measured
against what it changed and not against another day's load.

With --save, the figures go to bench/cost.json, the landed ones, with the commit they are of;
with --compare, each row is also set against that file's (another sitting's: a rough guide, where
--baseline is the measure).

Run: .venv/bin/python bench/cost.py [--times lockstep,max,real] [--systems 1,2] [--baseline REV]
     [--duration S] [--repeats N] [--variant SECTION.FIELD=VALUE ...] [--save] [--compare].
     Prints figures; asserts nothing."""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tarfile
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
STATIONS = ("simulation", "onboard", "vessel", "onshore")
LANDED = ROOT / "bench" / "cost.json"  # the landed figures (--save, --compare)


@dataclass(frozen=True)
class Tree:
    """What runs: a package directory on PYTHONPATH (None: this checkout), with these settings."""

    python_path: Path | None
    fields: tuple[str, ...] = ()  # `abyss up --set` SECTION.FIELD=VALUE


@dataclass(frozen=True)
class Run:
    verdict: str
    sim_s: float
    wall_s: float  # the mission's, from the first tick
    cpu_s: dict[str, float]  # per station, from its session's opening (the summary's cpu_s)
    tree_cpu_s: float  # the whole run's: the launcher and every process, imports included

    @property
    def speed(self) -> float:
        return self.sim_s / self.wall_s if self.wall_s else 0.0

    def per_sim_s(self, station: str) -> float:
        return self.cpu_s[station] / self.sim_s


def source_tree(revision: str, into: Path) -> Path:
    """`revision` of this repository as a package directory `abyss` under `into` (PYTHONPATH)."""
    package = into / "abyss"
    package.mkdir(parents=True)
    archive = into / "tree.tar"
    subprocess.run(["git", "archive", "-o", str(archive), revision], cwd=ROOT, check=True)
    with tarfile.open(archive) as tar:
        tar.extractall(package, filter="data")
    return into


def one_run(tree: Tree, time_source: str, out: Path, port: int, duration_s: float) -> Run:
    """The default mission on `time_source` (real, lockstep or max: `--time sim --speed max`)."""
    command = [sys.executable, "-m", "abyss.cli", "up", "--out", str(out)]  # as a user runs it: rerun saved
    command += [arg for field in tree.fields for arg in ("--set", field)]
    command += ["--port", str(port), "--system", f"cost-{port}", "--duration", f"{duration_s:g}"]
    command += {"real": [], "lockstep": ["--time", "lockstep"], "max": ["--time", "sim", "--speed", "max"]}[
        time_source
    ]
    env = dict(os.environ, **({"PYTHONPATH": str(tree.python_path)} if tree.python_path else {}))
    out.parent.mkdir(parents=True, exist_ok=True)
    process = subprocess.Popen(
        command, cwd=out.parent, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    _, status, usage = os.wait4(process.pid, 0)  # the whole tree's: launcher, stations, sensors
    process.returncode = os.waitstatus_to_exitcode(status)  # reaped here, not by Popen
    summary = json.loads((out / "summary.json").read_text())
    stations = summary["stations"]
    cpu_s = {s: float(stations[s]["cpu"]["cpu_s"]) for s in STATIONS}
    timing = summary.get("time", {})
    sim_s = float(timing.get("sim_s") or summary["simulation"]["sim_time_s"])
    wall_s = float(timing.get("wall_s") or sim_s)
    return Run(summary["verdict"], sim_s, wall_s, cpu_s, usage.ru_utime + usage.ru_stime)


def runs(tree: Tree, time_source: str, systems: int, tmp: Path, duration_s: float) -> list[Run]:
    """`systems` default missions at once."""
    outs = [tmp / f"{time_source}-{systems}-{i}-{time.monotonic_ns()}" for i in range(systems)]
    with ThreadPoolExecutor(systems) as pool:
        return list(
            pool.map(
                lambda i: one_run(tree, time_source, outs[i], 17447 + 10 * i, duration_s),
                range(systems),
            )
        )


def line(label: str, results: list[Run]) -> dict[str, float]:
    """Print one row: per station core-s per simulated second, the total, the speed."""
    sim_s = sum(r.sim_s for r in results)
    per = {s: sum(r.cpu_s[s] for r in results) / sim_s for s in STATIONS}
    total = sum(per.values())
    whole = sum(r.tree_cpu_s for r in results) / sim_s
    speeds = ", ".join(f"x{r.speed:.2f}" for r in results)
    verdicts = ", ".join(r.verdict for r in results)
    cells = "  ".join(f"{per[s]:6.3f}" for s in STATIONS)
    print(f"  {label:52s} {cells}  {total:6.3f}  {whole:6.3f}   {speeds} ({verdicts})", flush=True)
    return {**per, "total": total, "whole": whole, "speed": sum(r.speed for r in results) / len(results)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--times", default="lockstep,max,real", help="time sources: real, lockstep, max")
    parser.add_argument("--systems", default="1,2", help="systems at once, e.g. 1,2")
    parser.add_argument("--baseline", default="", help="a git revision to measure in the same sitting")
    parser.add_argument("--duration", type=float, default=90.0, help="--duration of each run [s]")
    parser.add_argument("--repeats", type=int, default=1, help="runs of each, interleaved, pooled")
    parser.add_argument(
        "--variant",
        action="append",
        default=[],
        metavar="SECTION.FIELD=VALUE",
        help="also this checkout with this setting (`abyss up --set`), in the same sitting; repeatable",
    )
    parser.add_argument("--save", action="store_true", help=f"write this checkout's figures to {LANDED.name}")
    parser.add_argument("--compare", action="store_true", help=f"set each row against {LANDED.name}'s")
    args = parser.parse_args()
    landed = json.loads(LANDED.read_text())["figures"] if args.compare and LANDED.is_file() else {}
    with tempfile.TemporaryDirectory(prefix="abyss-cost-") as tmp_dir:
        tmp = Path(tmp_dir)
        trees = {"now": Tree(None)}  # the installed package: this checkout
        trees |= {f"now, {field}": Tree(None, (field,)) for field in args.variant}
        if args.baseline:
            trees[args.baseline] = Tree(source_tree(args.baseline, tmp / "baseline"))
        print(
            "core-s per simulated second: each station from its session's opening, with its sensor "
            "processes (summary.json's cpu_s), their total, and the whole run's process tree (the "
            "launcher, every import and start-up):"
        )
        print(
            f"  {'':52s} "
            + "  ".join(f"{s[:6]:>6s}" for s in STATIONS)
            + "   total   whole   speed (verdict)"
        )
        figures: dict[tuple[str, str, int], dict[str, float]] = {}
        for time_source in args.times.split(","):
            for systems in map(int, args.systems.split(",")):
                done: dict[str, list[Run]] = {name: [] for name in trees}
                for _ in range(args.repeats):  # interleaved: the machine's drift lands on each alike
                    for name, tree in trees.items():
                        done[name] += runs(tree, time_source, systems, tmp, args.duration)
                for name, results in done.items():
                    label = f"{time_source}, {systems} at once, {name}"
                    figures[(name, time_source, systems)] = line(label, results)
                now = figures[("now", time_source, systems)]
                if args.compare:
                    before = landed.get(f"{time_source}, {systems} at once")
                    print(
                        f"  {'':52s} now/landed: cost {now['total'] / before['total']:.2f} (whole "
                        f"{now['whole'] / before['whole']:.2f}), speed {now['speed'] / before['speed']:.2f}"
                        if before
                        else f"  {'':52s} no landed figures for {time_source}, {systems} at once",
                        flush=True,
                    )
                for name in (n for n in trees if n.startswith("now, ")):
                    variant = figures[(name, time_source, systems)]
                    print(
                        f"  {'':52s} {name[5:]}/now: cost {variant['total'] / now['total']:.2f}, "
                        f"speed {variant['speed'] / now['speed']:.2f}",
                        flush=True,
                    )
                if args.baseline:
                    now, before = (
                        figures[("now", time_source, systems)],
                        figures[(args.baseline, time_source, systems)],
                    )
                    print(
                        f"  {'':52s} now/before: cost {now['total'] / before['total']:.2f} (whole "
                        f"{now['whole'] / before['whole']:.2f}), speed {now['speed'] / before['speed']:.2f}",
                        flush=True,
                    )

        if args.save:
            commit = subprocess.run(
                ["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True
            ).stdout.strip()
            mine = {
                f"{t}, {n} at once": {k: round(v, 4) for k, v in f.items()}
                for (name, t, n), f in figures.items()
                if name == "now"
            }
            LANDED.write_text(
                json.dumps(
                    {
                        "commit": commit,
                        "date": time.strftime("%Y-%m-%d"),
                        "repeats": args.repeats,
                        "figures": mine,
                    },
                    indent=2,
                )
                + "\n"
            )
            print(f"saved to {LANDED.relative_to(ROOT)} (at {commit})")


if __name__ == "__main__":
    main()
