"""The TCP model against kernel TCP through the TUN shaper: the full table (issue #17).

Every case of abyss.validation.tcpcheck (tether, satellite, satellite at 1 % loss, tether at 10 %)
and phase (bulk; 1, 10, 100 kB messages), through the model (--model-seeds seeds) and each
kernel variant (reno-textbook, reno, cubic through the TUN shaper; reno-netem, cubic-netem
through netem where the kernel has it: bench/shapers.py runs them inside UML; --kernel-seeds
seeds, a throw-away lab each).
Prints progress, then each metric's means and the ratio model / kernel (marked * where the two
differ by more than tcpcheck's TOLERANCE, widened by their spread); writes tcp_model.json (every
run's figures) and tcp_model.png (the ratios) to --out. As root, with /dev/net/tun; about 15
minutes. --kernel-from an earlier tcp_model.json takes its kernel runs instead of running them.
Run: .venv/bin/python bench/tcp_model.py [--out DIR] [--case NAME]... [--variant NAME]..."""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from abyss.validation.tcpcheck import compare
from abyss.validation.tcpcheck.compare import TOLERANCE, agreement, run_all
from abyss.validation.tcpcheck.kernel import kernel_unusable
from abyss.validation.tcpcheck.workload import CASES, VARIANTS, Job, Run

METRICS = {"bulk": ("goodput_bps", "retrans_per_packet", "timeouts_per_packet")}
LATENCY = ("latency_p50_s", "latency_p95_s")
UNITS = {
    "goodput_bps": (1e-3, "kbit/s"),
    "latency_p50_s": (1e3, "ms"),
    "latency_p95_s": (1e3, "ms"),
    "retrans_per_packet": (1e2, "%"),
    "timeouts_per_packet": (1e2, "%"),
}


def record(job: Job, run: Run) -> dict[str, Any]:
    """A run as tcp_model.json keeps it: the job, its figures and its counters."""
    return {
        "way": job.way,
        "case": job.case,
        "phase": job.phase,
        "seed": job.seed,
        **run.metrics(),
        "retransmissions": run.retransmissions,
        "timeouts": run.timeouts,
        **run.extra,
    }


def rows(records: list[dict[str, Any]], variants: list[str]) -> list[dict[str, Any]]:
    """One row per case, phase and metric: the mean of each way and model / kernel per variant."""
    table: list[dict[str, Any]] = []
    for case, phase in dict.fromkeys((r["case"], r["phase"]) for r in records):
        of = {
            way: [r for r in records if (r["way"], r["case"], r["phase"]) == (way, case, phase)]
            for way in ["model", *variants]
        }
        for metric in METRICS.get(phase, LATENCY):
            row: dict[str, Any] = {"case": case, "phase": phase, "metric": metric}
            for way, way_runs in of.items():
                row[way] = float(np.mean([r[metric] for r in way_runs])) if way_runs else math.nan
            for variant in variants:
                a = agreement(metric, of["model"], of[variant]) if of[variant] else None
                row[f"model/{variant}"] = a.ratio if a else math.nan
                row[f"agrees/{variant}"] = a.agrees if a else False
            for netem, tun in shaper_pairs(variants):  # the two real shapers against each other
                a = agreement(metric, of[netem], of[tun]) if of[netem] and of[tun] else None
                row[f"{netem}/{tun}"] = a.ratio if a else math.nan
                row[f"agrees/{netem}/{tun}"] = a.agrees if a else False
            table.append(row)
    return table


def shaper_pairs(variants: list[str]) -> list[tuple[str, str]]:
    """(netem variant, its TUN-shaped twin) for each pair among `variants`."""
    return [
        (v, v.removesuffix("-netem"))
        for v in variants
        if v.endswith("-netem") and v.removesuffix("-netem") in variants
    ]


def print_table(table: list[dict[str, Any]], variants: list[str]) -> None:
    pairs = [f"{netem}/{tun}" for netem, tun in shaper_pairs(variants)]
    head = f"{'case':<13}{'phase':<7}{'metric':<22}{'model':>10}" + "".join(f"{v:>15}" for v in variants)
    print(head + "".join(f"{'model/' + v:>20}" for v in variants) + "".join(f"{p:>20}" for p in pairs))
    for row in table:
        scale, unit = UNITS[str(row["metric"])]
        figures = "".join(
            f"{float(str(row[w])) * scale:>{15 if w != 'model' else 10}.4g}" for w in ["model", *variants]
        )
        ratios = "".join(
            f"{float(str(row['model/' + v])):>19.2f}{' ' if row['agrees/' + v] else '*'}" for v in variants
        )
        ratios += "".join(f"{float(str(row[p])):>19.2f}{' ' if row['agrees/' + p] else '*'}" for p in pairs)
        label = f"{row['metric']} [{unit}]"
        print(f"{row['case']:<13}{row['phase']:<7}{label:<22}{figures}{ratios}")
    print(f"* the two differ by more than {TOLERANCE:.0%} plus twice their standard error")


def plot(table: list[dict[str, Any]], variants: list[str], path: Path) -> None:
    cases = list(dict.fromkeys(str(r["case"]) for r in table))
    fig, axes = plt.subplots(len(cases), 1, figsize=(12, 3.2 * len(cases)), squeeze=False)
    for ax, case in zip(axes[:, 0], cases, strict=True):
        mine = [r for r in table if r["case"] == case]
        x = np.arange(len(mine))
        for i, variant in enumerate(variants):
            ratios = [min(max(float(str(r[f"model/{variant}"])), 1e-2), 1e2) for r in mine]
            ax.bar(
                x + (i - (len(variants) - 1) / 2) * 0.8 / len(variants),
                ratios,
                0.8 / len(variants),
                label=variant,
            )
        ax.axhspan(1 - TOLERANCE, 1 + TOLERANCE, color="0.85", zorder=0)
        ax.axhline(1.0, color="k", lw=0.8)
        ax.set_yscale("log")
        ax.set_xticks(
            x, [f"{r['phase']}\n{str(r['metric']).replace('_per_packet', '/pkt')}" for r in mine], fontsize=7
        )
        ax.set_ylabel("model / kernel")
        ax.set_title(case)
        ax.legend(fontsize=7, ncol=len(variants))
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, default=Path("bench/results/tcp_model"))
    parser.add_argument("--case", action="append", choices=list(CASES), dest="cases")
    parser.add_argument("--variant", action="append", choices=list(VARIANTS), dest="variants")
    parser.add_argument("--phase", action="append", dest="phases", help="bulk, 1kB, 10kB, 100kB")
    parser.add_argument("--kernel-seeds", type=int, default=5)
    parser.add_argument("--model-seeds", type=int, default=10)
    parser.add_argument("--labs", type=int, default=compare.MAX_LABS, help="kernel runs at once, at most")
    parser.add_argument(
        "--kernel-from",
        type=Path,
        metavar="JSON",
        help="kernel runs from an earlier tcp_model.json: its variants are not run again",
    )
    args = parser.parse_args()
    cases = args.cases or list(CASES)
    variants = args.variants or [v for v in VARIANTS if VARIANTS[v].shaper == "tun"]
    wanted = [
        (case, phase)
        for case in cases
        for phase in CASES[case].phases
        if not args.phases or phase in args.phases
    ]
    earlier: list[dict[str, Any]] = []
    if args.kernel_from:
        earlier = [
            r
            for r in json.loads(args.kernel_from.read_text())["runs"]
            if r["way"] in variants and (r["case"], r["phase"]) in wanted
        ]
    to_run = [v for v in variants if v not in {r["way"] for r in earlier}]
    if to_run and (reason := kernel_unusable(to_run)):
        print(f"bench/tcp_model.py: {reason}", file=sys.stderr)
        return 2
    jobs = [
        Job(way, case, phase, seed)
        for case, phase in wanted
        for way in ["model", *to_run]
        for seed in range(args.model_seeds if way == "model" else args.kernel_seeds)
    ]
    compare.MAX_LABS = args.labs
    started_s = time.monotonic()
    runs = run_all(jobs, echo=lambda line: print(line, flush=True))
    print(f"{len(jobs)} runs in {time.monotonic() - started_s:.0f} s\n")
    records = [record(job, run) for job, run in runs.items()] + earlier
    table = rows(records, variants)
    print_table(table, variants)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "tcp_model.json").write_text(json.dumps({"table": table, "runs": records}, indent=1))
    plot(table, variants, args.out / "tcp_model.png")
    print(f"written: {args.out / 'tcp_model.json'}, {args.out / 'tcp_model.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
