"""The statistics of a campaign's verdicts: a pass rate with its Wilson score interval, which
stays inside [0, 1] and is honest at 0 and at every pass, where the normal approximation is not."""

from __future__ import annotations

import math


def wilson(passes: int, runs: int, z: float = 1.96) -> tuple[float, float]:
    """The Wilson score interval (low, high) of a pass rate of `passes` in `runs`, at `z` standard
    deviations (1.96: 95 %); (0, 1) for no runs."""
    if runs <= 0:
        return 0.0, 1.0
    if not 0 <= passes <= runs:
        raise ValueError(f"{passes} passes in {runs} runs")
    p = passes / runs
    z2 = z * z
    denominator = 1.0 + z2 / runs
    center = (p + z2 / (2 * runs)) / denominator
    half = z / denominator * math.sqrt(p * (1.0 - p) / runs + z2 / (4 * runs * runs))
    low = 0.0 if passes == 0 else max(0.0, center - half)
    high = 1.0 if passes == runs else min(1.0, center + half)
    return low, high


def flaky(passes: int, runs: int) -> bool:
    """Neither always passing nor always failing."""
    return 0 < passes < runs
