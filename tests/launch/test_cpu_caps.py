"""CPU caps (`launch/cpu.py`): a real cgroup quota on a real busy process holds it to its cap, the
group is gone afterwards with the share of periods it was throttled in; without a writable cgroup
`--cpu` fails at start naming itself; bad caps fail at load naming the field."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest

from abyss.cli import parser
from abyss.cli.args import load_config
from abyss.common.errors import ConfigError
from abyss.config import load
from abyss.launch.cpu import CpuCaps, find_controller

BUSY = "import time\nprint('ready', flush=True)\nwhile True:\n    pass\n"


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / 100.0  # utime + stime, in clock ticks of 10 ms


@pytest.mark.skipif(find_controller() is None, reason="no writable cgroup with the cpu controller (not root)")
def test_a_capped_busy_process_gets_its_cap_and_the_group_goes_afterwards() -> None:
    caps = CpuCaps("captest", {"onboard": 0.2})
    busy = subprocess.Popen([sys.executable, "-c", BUSY], stdout=subprocess.PIPE)
    try:
        assert busy.stdout is not None and busy.stdout.readline() == b"ready\n"
        caps.apply("onboard", busy.pid)
        caps.apply("vessel", busy.pid)  # not capped: nothing happens
        start_cpu_s, start_s = cpu_seconds(busy.pid), time.monotonic()
        time.sleep(2.0)  # the measurement's window: a rate over time, not an event to wait for
        cores = (cpu_seconds(busy.pid) - start_cpu_s) / (time.monotonic() - start_s)
    finally:
        busy.kill()
        busy.communicate()
    group = caps.groups["onboard"]
    caps.close()
    # measured: 0.20 core (a busy loop alone takes a whole one)
    assert 0.1 < cores < 0.3, cores
    assert not group.exists()
    assert caps.throttled_share["onboard"] > 0.5  # a busy loop hits its quota in nearly every period


def test_without_a_writable_cgroup_cpu_fails_at_start_naming_it(tmp_path: Path) -> None:
    mounts = tmp_path / "mounts"
    mounts.write_text("proc /proc proc rw 0 0\ncgroup2 /nonexistent cgroup2 rw 0 0\n")
    with pytest.raises(ConfigError, match=r"--cpu: .*writable cgroup with the cpu controller"):
        CpuCaps("captest", {"onboard": 0.3}, mounts)
    assert CpuCaps("captest", {}, mounts).groups == {}  # nothing capped: nothing asked of the host


def test_bad_caps_fail_at_load_naming_the_field() -> None:
    assert load(None, ["cpu.onboard=0.3"]).cpu.capped() == {"onboard": 0.3}
    with pytest.raises(ConfigError, match=r"cpu\.onboard.*0\.01 cores: 0 \(uncapped\) or 0\.05"):
        load(None, ["cpu.onboard=0.01"])
    with pytest.raises(ConfigError, match=r"cpu\.lidar.*allowed: onboard, onshore, simulation, vessel"):
        load(None, ["cpu.lidar=0.3"])
    args = parser().parse_args(["up", "--cpu", "onboard=0.5", "--cpu", "vessel=1"])
    assert load_config(args).cpu.capped() == {"onboard": 0.5, "vessel": 1.0}
    with pytest.raises(ConfigError, match="lidar"):
        load_config(parser().parse_args(["up", "--cpu", "lidar=0.5"]))
    with pytest.raises(ConfigError, match=r"--cpu.*not KEY=VALUE"):
        load_config(parser().parse_args(["up", "--cpu", "onboard"]))
