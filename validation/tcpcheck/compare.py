"""The TCP comparison's runs, made (the model's in turn, the kernel's in labs side by side) and
weighed (`Agreement`: model against kernel on one metric over the seeds)."""

from __future__ import annotations

import math
import subprocess
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from abyss.common.errors import LinkError
from abyss.validation.tcpcheck.kernel import run_kernel
from abyss.validation.tcpcheck.model import run_model
from abyss.validation.tcpcheck.workload import CASES, Job, Run

KERNEL_BUDGET_BPS = 12e6  # what the TUN shapers of kernel runs at once may offer (a CPU's worth)
MAX_LABS = 24  # kernel runs at once, whatever their load
TOLERANCE = 0.25  # model / kernel within 1 +- TOLERANCE, widened by the measurement's spread


def run(job: Job) -> Run:
    case = CASES[job.case]
    if job.way == "model":
        return run_model(case, case.phase(job.phase), job.seed)
    return run_kernel(case, job.way, case.phase(job.phase), job.seed)


def run_all(jobs: Sequence[Job], echo: Callable[[str], None] = lambda _: None) -> dict[Job, Run]:
    """Every job: the model's in turn, then the kernel's, a lab each, as many at once as the
    shapers can carry (their offered loads within KERNEL_BUDGET_BPS, at most MAX_LABS labs);
    `echo` hears of each as it ends. A kernel run that fails is told to `echo` and left out."""
    runs: dict[Job, Run] = {}
    started_s = time.monotonic()
    for job in jobs:
        if job.way == "model":
            runs[job] = run(job)
    echo(f"[{len(runs)}/{len(jobs)}] the model's runs ({time.monotonic() - started_s:.1f} s)")

    def load_bps(job: Job) -> float:
        return min(CASES[job.case].offered_bps(job.phase), KERNEL_BUDGET_BPS)

    in_use_bps = 0.0  # guarded by `budget`
    budget = threading.Condition()

    def one(job: Job) -> None:
        nonlocal in_use_bps
        with budget:
            budget.wait_for(lambda: in_use_bps + load_bps(job) <= KERNEL_BUDGET_BPS)
            in_use_bps += load_bps(job)
        job_started_s = time.monotonic()
        try:
            runs[job] = run(job)
        except (LinkError, OSError, subprocess.SubprocessError, ValueError) as exc:
            echo(f"[{len(runs)}/{len(jobs)}] {job}: FAILED, left out: {exc}")
            return
        finally:
            with budget:
                in_use_bps -= load_bps(job)
                budget.notify_all()
        figures = ", ".join(f"{k} {v:.3g}" for k, v in runs[job].metrics().items())
        echo(f"[{len(runs)}/{len(jobs)}] {job}: {figures} ({time.monotonic() - job_started_s:.1f} s)")

    kernel = sorted((job for job in jobs if job.way != "model"), key=load_bps, reverse=True)
    with ThreadPoolExecutor(MAX_LABS) as pool:
        list(pool.map(one, kernel))
    return {job: runs[job] for job in jobs if job in runs}


@dataclass(frozen=True)
class Agreement:
    """Model against kernel on one metric, each over its seeds. They agree when their means differ
    by at most TOLERANCE of the kernel's, plus `z` standard errors of the difference, plus
    `resolution` (a per-packet count's: one event per run, so that 0 against 1 in 200 agrees)."""

    model: tuple[float, ...]
    kernel: tuple[float, ...]
    resolution: float = 0.0
    z: float = 2.0

    @property
    def ratio(self) -> float:
        return _mean(self.model) / _mean(self.kernel) if _mean(self.kernel) else math.inf

    @property
    def allowed(self) -> float:
        """The largest difference of the means that agrees."""
        spread = math.hypot(_sem(self.model), _sem(self.kernel))
        return TOLERANCE * abs(_mean(self.kernel)) + self.z * spread + self.resolution

    @property
    def agrees(self) -> bool:
        return abs(_mean(self.model) - _mean(self.kernel)) <= self.allowed


def agreement(
    metric: str, model: Sequence[Mapping[str, float]], kernel: Sequence[Mapping[str, float]]
) -> Agreement:
    """`metric` of one phase's runs (as `Run.metrics()` gives them), the model's against the kernel's."""
    resolution = 1.0 / _mean([r["packets"] for r in kernel]) if metric.endswith("_per_packet") else 0.0
    return Agreement(tuple(r[metric] for r in model), tuple(r[metric] for r in kernel), resolution)


def _mean(values: Sequence[float]) -> float:
    return float(np.mean(values))


def _sem(values: Sequence[float]) -> float:
    return float(np.std(values, ddof=1) / math.sqrt(len(values))) if len(values) > 1 else 0.0
