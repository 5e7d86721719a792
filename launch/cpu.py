"""CPU caps for station processes: a cgroup per capped station with a CFS quota (cgroup v1's
`cpu` controller or cgroup v2's `cpu.max`), what `docker run --cpus` sets. The period is short
(10 ms rather than the kernel's 100 ms): a station capped at 0.3 core is held at most 7 ms at a
time, which a 50 ms control loop survives, instead of 70 ms, which it would not.

Each group is named after the system, the station and the supervisor's pid, under the
controller's root; `close()` removes the groups once their processes have ended, and reads
how often the kernel held each station back (`throttled_share`: of its periods)."""

from __future__ import annotations

import contextlib
import os
from dataclasses import dataclass
from pathlib import Path

from abyss.common.errors import ConfigError

CFS_PERIOD_US = 10_000
MOUNTS = Path("/proc/self/mounts")


@dataclass(frozen=True)
class Controller:
    root: Path
    version: int  # 1: the v1 `cpu` hierarchy; 2: the unified one


def find_controller(mounts: Path = MOUNTS) -> Controller | None:
    """The writable cgroup hierarchy that holds the cpu controller, if any."""
    for line in mounts.read_text().splitlines():
        _, where, kind, options, *_ = line.split()
        root = Path(where)
        if kind == "cgroup" and "cpu" in options.split(","):
            found = Controller(root, 1)
        elif kind == "cgroup2" and "cpu" in _words(root / "cgroup.controllers"):
            found = Controller(root, 2)
        else:
            continue
        if os.access(root, os.W_OK):
            return found
    return None


def _words(path: Path) -> list[str]:
    try:
        return path.read_text().split()
    except OSError:
        return []


class CpuCaps:
    """`caps`: station -> cores. Fails at construction, naming `--cpu`, where no cgroup can be
    written (not root, no delegated cgroup v2 subtree)."""

    def __init__(self, system: str, caps: dict[str, float], mounts: Path = MOUNTS) -> None:
        self.caps = dict(caps)
        self.groups: dict[str, Path] = {}
        self.throttled_share: dict[str, float] = {}
        self.controller = find_controller(mounts) if self.caps else None
        if self.caps and self.controller is None:
            raise ConfigError(
                "--cpu",
                "capping a station's CPU needs a writable cgroup with the cpu "
                "controller (run as root, or in a delegated cgroup v2 subtree); none in "
                f"{mounts}",
            )
        if self.controller is None:
            return
        if self.controller.version == 2:  # the children of the root get the cpu controller
            (self.controller.root / "cgroup.subtree_control").write_text("+cpu")
        for station, cores in self.caps.items():
            group = self.controller.root / f"abyss-{system}-{station}-{os.getpid()}"
            group.mkdir(exist_ok=True)
            quota_us = max(1000, round(cores * CFS_PERIOD_US))  # the kernel's least quota is 1 ms
            if self.controller.version == 1:
                (group / "cpu.cfs_period_us").write_text(str(CFS_PERIOD_US))
                (group / "cpu.cfs_quota_us").write_text(str(quota_us))
            else:
                (group / "cpu.max").write_text(f"{quota_us} {CFS_PERIOD_US}")
            self.groups[station] = group

    def apply(self, station: str, pid: int) -> None:
        """Put process `pid` (all its threads) in `station`'s group, if it is capped."""
        group = self.groups.get(station)
        if group is not None:
            (group / "cgroup.procs").write_text(str(pid))

    def close(self) -> None:
        """Read how often each group was throttled and remove the groups (their processes have
        ended)."""
        for station, group in self.groups.items():
            stat = dict(line.split() for line in _lines(group / "cpu.stat"))  # v1 and v2 alike
            periods = int(stat.get("nr_periods", 0))
            self.throttled_share[station] = int(stat.get("nr_throttled", 0)) / periods if periods else 0.0
            with contextlib.suppress(OSError):  # a process of it still running: the kernel keeps the group
                group.rmdir()
        self.groups.clear()


def _lines(path: Path) -> list[str]:
    try:
        return [line for line in path.read_text().splitlines() if len(line.split()) == 2]
    except OSError:
        return []
