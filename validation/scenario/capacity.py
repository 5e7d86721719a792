"""How many whole systems this machine runs at once in real time (`abyss scenario run --parallel
auto`): the cores this process may use (its CPU affinity, and its cgroup's quota where one is set)
kept at HEADROOM, over what a whole system costs here. The cost is measured: each scenario run
adds its systems' CPU (the stations' process time over wall time, from their summaries) to a
small file in the user's cache, and the median of the latest ones is used; before any run here,
the figure measured on the project's own 2-core machine."""

from __future__ import annotations

import json
import math
import os
import statistics
from collections.abc import Iterable
from pathlib import Path
from typing import Any

HEADROOM = 0.8  # of the cores, for the systems: the rest for the runner, the routers and the host
REFERENCE_CORES = 0.6  # the default mission with its recording, measured on the project's machine (0.52-0.66)
KEPT = 32  # the latest systems' costs kept


def cost_file() -> Path:
    cache = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(cache) / "abyss" / "system_cores.json"


def available_cores() -> float:
    """The CPUs this process may run on, fewer where the cgroup it sees as its root has a quota (a
    container's --cpus)."""
    cores = float(len(os.sched_getaffinity(0)))
    quotas = (
        (Path("/sys/fs/cgroup/cpu.max"), _v2_quota),
        (Path("/sys/fs/cgroup/cpu/cpu.cfs_quota_us"), _v1_quota),
    )
    for path, parse in quotas:
        try:
            quota = parse(path)
        except (OSError, ValueError):
            continue
        if quota is not None:
            cores = min(cores, quota)
    return cores


def _v2_quota(path: Path) -> float | None:
    quota, period = path.read_text().split()
    return None if quota == "max" else int(quota) / int(period)


def _v1_quota(path: Path) -> float | None:
    quota = int(path.read_text())
    period = int((path.parent / "cpu.cfs_period_us").read_text())
    return None if quota < 0 else quota / period


def measured_cores() -> tuple[float, str]:
    """Cores per whole system, and where the figure comes from."""
    try:
        costs = [float(c) for c in json.loads(cost_file().read_text())["cores"]]
    except (OSError, ValueError, KeyError, TypeError):
        costs = []
    costs = [c for c in costs if math.isfinite(c) and c > 0]
    if not costs:
        return REFERENCE_CORES, "the project's measurement (none here yet)"
    return statistics.median(costs), f"the median of the latest {len(costs)} systems run here"


def record(summaries: Iterable[dict[str, Any]]) -> None:
    """Keep the cost of each system that ran (its stations' cores summed), per simulated second
    (a system at speed X takes X times its real-time cores)."""
    new = [
        sum(s["cpu"]["cores"] for s in summary.get("stations", {}).values() if s.get("cpu"))
        / max(summary.get("time", {}).get("achieved_speed", 1.0), 1e-3)
        for summary in summaries
    ]
    new = [c for c in new if c > 0]
    if not new:
        return
    path = cost_file()
    try:
        old = json.loads(path.read_text())["cores"]
    except (OSError, ValueError, KeyError, TypeError):
        old = []
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"cores": [*old, *new][-KEPT:]}))


def auto_parallel(scenarios: int, speed: float = 1.0) -> tuple[int, str]:
    """How many systems at once at `speed` (simulated seconds per wall second; inf: as fast as
    each can, a core each), and the sentence that says why."""
    cores = available_cores()
    per_system, source = measured_cores()
    per_system_at_speed = per_system * speed if math.isfinite(speed) else 1.0
    count = max(1, min(scenarios, math.floor(HEADROOM * cores / per_system_at_speed)))
    at = "" if speed == 1.0 else f" at speed {speed:g}" if math.isfinite(speed) else " at speed max"
    return count, (
        f"--parallel auto: {count} systems at once{at} ({cores:g} cores here, {HEADROOM:.0%} of "
        f"them for the systems; a system takes {per_system_at_speed:.2f} cores{at}, {source})"
    )
