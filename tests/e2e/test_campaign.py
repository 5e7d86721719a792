"""Campaigns on Ray as a team runs them: a small campaign on a local Ray judged as pass rates (its
counts, Wilson intervals and JUnit), the same campaign as two shards, one of them with its driver
SIGKILLed mid-way and resumed, merged into the one campaign's report; two Ray nodes in two
network namespaces sharing a campaign, the worker killed mid-way and its run retried on the head;
and a failing run with a fault and a kill replayed byte for byte."""

from __future__ import annotations

import contextlib
import json
import math
import os
import re
import secrets
import shutil
import signal
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import abyss

from abyss.validation.campaign.stats import wilson

SCENARIOS = Path(__file__).parent / "campaign"
SEEDS = 2
CAMPAIGN = f"""\
name = "small"
scenarios = ["scenarios/short-*.toml"]
seeds = {SEEDS}
time = "lockstep"

[matrix]
"links.satellite" = ["satellite", "satellite-storm"]
"""


def campaign_dir(tmp_path: Path, text: str = CAMPAIGN, names: tuple[str, ...] = ("short-links",)) -> Path:
    """A campaign file and its scenarios in a directory of the user's."""
    (tmp_path / "scenarios").mkdir()
    for name in names:
        shutil.copy(SCENARIOS / f"{name}.toml", tmp_path / "scenarios")
    (tmp_path / "small.toml").write_text(text)
    return tmp_path


def records(out: Path) -> list[dict[str, object]]:
    lines = (out / "results.jsonl").read_text().splitlines() if (out / "results.jsonl").exists() else []
    return [json.loads(line) for line in lines if line.endswith("}")]


def driver(
    here: Path, *args: str, env: dict[str, str] | None = None, prefix: tuple[str, ...] = ()
) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [*prefix, sys.executable, "-P", "-m", "abyss.cli", "campaign", "run", *args],
        cwd=here,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})},
    )


def wait_for_records(
    out: Path, count: int, process: subprocess.Popen[str], timeout_s: float
) -> list[dict[str, object]]:
    """The store once it holds `count` records (the driver still running)."""
    deadline = time.monotonic() + timeout_s
    while len(got := records(out)) < count:
        assert process.poll() is None, process.stdout.read() if process.stdout else ""
        assert time.monotonic() < deadline, f"{len(got)} of {count} records in {timeout_s} s"
        time.sleep(0.2)
    return got


def comparable(report: Path) -> dict[str, object]:
    """A report without what each execution measures of itself (the cost, and the cores each run
    took): the rest is the same for the same runs in lockstep, however they were spread."""
    data = json.loads((report / "report.json").read_text())
    data.pop("cost")
    for case in data["cases"]:
        case["figures"].pop("cores")
    return data


@pytest.mark.timeout(900)
def test_a_campaign_on_local_ray_then_two_shards_one_killed_and_resumed_merge_to_its_report(
    tmp_path: Path,
) -> None:
    here = campaign_dir(tmp_path)
    whole = abyss("campaign", "run", "small.toml", "--out", "whole", timeout_s=600, cwd=here)
    assert whole.returncode == 1, whole.stdout + whole.stderr  # the storm fails short-links' delay bound
    out = here / "whole"
    got = records(out)
    runs = 2 * SEEDS  # one scenario (what the glob finds) by two variants
    assert len(got) == runs and len({r["run_id"] for r in got}) == runs
    report = json.loads((out / "report.json").read_text())
    groups = {(g["scenario"], g["variant"]): g for g in report["cases"]}
    assert len(groups) == 2
    for (scenario, variant), group in groups.items():
        mine = [r for r in got if r["scenario"] == scenario and r["variant"] == variant]
        passes = sum(bool(r["passed"]) for r in mine)
        assert group["runs"] == SEEDS and group["passes"] == passes
        low, high = wilson(passes, SEEDS)
        assert math.isclose(group["wilson_95"][0], low) and math.isclose(group["wilson_95"][1], high)
        assert group["flaky"] == (0 < passes < SEEDS)
    storm = groups[("short-links", "links.satellite=satellite-storm")]
    assert storm["passes"] == 0 and storm["assertion_failures"], storm
    assert groups[("short-links", "links.satellite=satellite")]["passes"] == SEEDS
    cases = {
        (c.get("classname"), c.get("name")): c for c in ET.parse(out / "junit.xml").getroot().iter("testcase")
    }
    assert len(cases) == 2
    failed = {k for k, c in cases.items() if c.find("failure") is not None}
    assert ("campaign.short-links", "links.satellite=satellite-storm") in failed
    assert all(r["kept"] for r in got if not r["passed"]) and not any(r["kept"] for r in got if r["passed"])
    failing = next(r for r in got if not r["passed"])
    assert (out / str(failing["kept"]) / "control.csv").exists()
    assert "abyss campaign replay" in (out / "report.md").read_text()

    # the same campaign in two shards; the first's driver SIGKILLed after its first result (one
    # run at a time here: a lockstep run asks Ray for more than half this machine's cores)
    first = driver(here, "small.toml", "--out", "s1", "--shard", "1/2")
    try:
        wait_for_records(here / "s1", 1, first, 300)
    finally:
        os.killpg(first.pid, signal.SIGKILL)
        first.communicate()  # its output pipe closed with it
    kept = len(records(here / "s1"))
    resumed = abyss(
        "campaign", "run", "small.toml", "--out", "s1", "--shard", "1/2", "--resume", timeout_s=600, cwd=here
    )
    assert f"{kept} have results, {runs // 2 - kept} to run" in resumed.stdout, (
        resumed.stdout + resumed.stderr
    )
    assert (
        len(records(here / "s1")) == runs // 2
        and len({r["run_id"] for r in records(here / "s1")}) == runs // 2
    )
    second = abyss("campaign", "run", "small.toml", "--out", "s2", "--shard", "2/2", timeout_s=600, cwd=here)
    assert second.returncode in (0, 1), second.stdout + second.stderr
    merged = abyss("campaign", "merge", "s1", "s2", "--out", "merged", timeout_s=120, cwd=here)
    assert merged.returncode == whole.returncode, merged.stdout + merged.stderr
    assert comparable(here / "merged") == comparable(out)


class RayNodes:
    """A Ray head and a Ray worker, each in a network namespace of its own, joined by a veth pair."""

    def __init__(self) -> None:
        tag = secrets.token_hex(3)
        self.spaces = (f"rh-{tag}", f"rw-{tag}")
        self.addresses = ("10.79.0.1", "10.79.0.2")
        self.env = {**os.environ, "RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": secrets.token_hex(32)}
        self.port = 6390

    def ip(self, *args: str) -> None:
        subprocess.run(["ip", *args], check=True, capture_output=True)

    def make(self, worker_env: dict[str, str] | None = None) -> RayNodes:
        head, worker = self.spaces
        for space in self.spaces:
            self.ip("netns", "add", space)
            self.ip("-n", space, "link", "set", "lo", "up")
        self.ip("link", "add", "rv0", "netns", head, "type", "veth", "peer", "name", "rv1", "netns", worker)
        for space, device, address in zip(self.spaces, ("rv0", "rv1"), self.addresses, strict=True):
            self.ip("-n", space, "addr", "add", f"{address}/24", "dev", device)
            self.ip("-n", space, "link", "set", device, "up")
        ray = str(Path(sys.executable).with_name("ray"))
        common = ["--num-cpus", "2", "--disable-usage-stats"]
        self.start(
            head,
            [
                ray,
                "start",
                "--head",
                "--node-ip-address",
                self.addresses[0],
                "--port",
                str(self.port),
                "--include-dashboard",
                "false",
                *common,
            ],
        )
        self.start(
            worker,
            [
                ray,
                "start",
                "--address",
                f"{self.addresses[0]}:{self.port}",
                "--node-ip-address",
                self.addresses[1],
                *common,
            ],
            worker_env,
        )
        return self

    def start(self, space: str, command: list[str], env: dict[str, str] | None = None) -> None:
        done = subprocess.run(
            ["ip", "netns", "exec", space, *command],
            env={**self.env, **(env or {})},
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert done.returncode == 0, done.stdout + done.stderr

    def driver(self, here: Path) -> subprocess.Popen[str]:
        """`campaign run small.toml --out out` on the head's node, joined to its cluster."""
        address = f"{self.addresses[0]}:{self.port}"
        prefix = ("ip", "netns", "exec", self.spaces[0])
        return driver(here, "small.toml", "--out", "out", "--address", address, env=self.env, prefix=prefix)

    def kill(self, space: str) -> None:
        pids = subprocess.run(["ip", "netns", "pids", space], capture_output=True, text=True).stdout.split()
        for pid in pids:
            with contextlib.suppress(ProcessLookupError):
                os.kill(int(pid), signal.SIGKILL)

    def remove(self) -> None:
        for space in self.spaces:
            self.kill(space)
            subprocess.run(["ip", "netns", "del", space], capture_output=True)


def other_abyss(tmp_path: Path) -> Path:
    """A copy of abyss's package with one source line more: another version of abyss, importable
    from the folder returned (on PYTHONPATH, ahead of the installed one)."""
    import abyss
    from abyss.validation.campaign.version import _package_files

    root = Path(abyss.__file__).resolve().parent
    site = tmp_path / "other-abyss"
    for path in _package_files(root):
        copy = site / "abyss" / path.relative_to(root)
        copy.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(path, copy)
    with (site / "abyss" / "__init__.py").open("a") as init:
        init.write("# another abyss\n")
    return site


@contextlib.contextmanager
def two_nodes(worker_env: dict[str, str] | None = None) -> Iterator[RayNodes]:
    if os.geteuid() != 0 or shutil.which("ip") is None:
        pytest.skip("two Ray nodes in network namespaces need root and iproute2")
    nodes = RayNodes()
    try:
        yield nodes.make(worker_env)
    finally:
        nodes.remove()


@pytest.fixture
def ray_nodes() -> Iterator[RayNodes]:
    with two_nodes() as nodes:
        yield nodes


@pytest.fixture
def ray_nodes_other_abyss(tmp_path: Path) -> Iterator[RayNodes]:
    """Two Ray nodes, the worker running another version of abyss."""
    with two_nodes({"PYTHONPATH": str(other_abyss(tmp_path))}) as nodes:
        yield nodes


@pytest.mark.timeout(900)
def test_two_ray_nodes_share_a_campaign_and_a_dead_workers_run_is_retried_on_the_head(
    tmp_path: Path, ray_nodes: RayNodes
) -> None:
    text = CAMPAIGN.replace(f"seeds = {SEEDS}", "seeds = 6").replace(
        'scenarios = ["scenarios/short-*.toml"]', 'scenarios = ["scenarios/short-mission.toml"]'
    )
    text = text.split("[matrix]")[0]
    here = campaign_dir(tmp_path, text, ("short-mission",))
    head, worker = ray_nodes.addresses
    run = ray_nodes.driver(here)
    deadline = time.monotonic() + 400
    try:
        while not any(worker in str(r["node"]) for r in records(here / "out")):
            assert run.poll() is None and time.monotonic() < deadline, "no run on the worker in time"
            time.sleep(0.2)
    except AssertionError:
        os.killpg(run.pid, signal.SIGKILL)
        raise AssertionError(run.communicate()[0]) from None
    ray_nodes.kill(ray_nodes.spaces[1])  # the worker's node dies with the run it has just started
    output, _ = run.communicate(timeout=600)
    assert run.returncode == 0, output
    got = records(here / "out")
    assert len(got) == 6 and len({r["run_id"] for r in got}) == 6, got  # none lost, none twice
    nodes = [str(r["node"]) for r in got]
    assert any(head in n for n in nodes) and any(worker in n for n in nodes), nodes
    assert "2 nodes" in output and "6/6 runs done" in output, output


@pytest.mark.timeout(600)
def test_a_failing_run_with_a_fault_a_link_change_and_a_kill_replays_byte_for_byte(tmp_path: Path) -> None:
    text = 'name = "replayed"\nscenarios = ["scenarios/short-faults.toml"]\nseeds = [7]\ntime = "lockstep"\n'
    here = campaign_dir(tmp_path, text, ("short-faults",))
    run = abyss("campaign", "run", "small.toml", "--out", "out", timeout_s=300, cwd=here)
    assert run.returncode == 1, run.stdout + run.stderr  # it allows no restart: it fails
    [record] = records(here / "out")
    kept = here / "out" / str(record["kept"])
    assert not record["passed"] and (kept / "record" / "onboard-1.mcap").exists()  # onboard's second life
    assert "not bit for bit" not in (here / "out" / "report.md").read_text()

    replayed = abyss("campaign", "replay", "out", str(record["run_id"])[:8], timeout_s=300, cwd=here)
    said = replayed.stdout + replayed.stderr
    assert replayed.returncode == 0, said
    compared = re.search(r"byte-identical: control.csv and (\d+) messages", said)
    assert compared and int(compared.group(1)) > 1000, said
    assert "ended on different periods" not in said  # it runs to its duration: the same last period

    rows = (kept / "control.csv").read_text().splitlines()
    rows[len(rows) // 2] = rows[len(rows) // 2].replace("0", "1", 1)  # one digit of one row
    (kept / "control.csv").write_text("\n".join(rows) + "\n")
    again = abyss("campaign", "replay", "out", str(record["run_id"]), timeout_s=300, cwd=here)
    assert again.returncode == 1 and "DIFFERS: control.csv differs" in again.stdout, (
        again.stdout + again.stderr
    )


@pytest.mark.timeout(300)
def test_a_node_with_another_abyss_is_refused_at_start_naming_both_versions(
    tmp_path: Path, ray_nodes_other_abyss: RayNodes
) -> None:
    ray_nodes = ray_nodes_other_abyss
    from abyss.validation.campaign.version import abyss_version

    here = campaign_dir(tmp_path, CAMPAIGN.split("[matrix]")[0], ("short-mission",))
    run = ray_nodes.driver(here)
    output, _ = run.communicate(timeout=240)
    assert run.returncode == 2, output
    theirs = re.search(r"node \S+/10\.79\.0\.2 runs abyss (\S+), this driver (\S+):", output)
    assert theirs, output
    assert theirs.group(2) == abyss_version() and theirs.group(1) != abyss_version(), output
    assert not records(here / "out")  # nothing ran
