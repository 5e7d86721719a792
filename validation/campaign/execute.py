"""`abyss campaign run`: a campaign's runs as Ray tasks. With no address a local Ray starts inside
the command; with one the driver joins that cluster. Each run is a task that asks for the cores a
system costs (fractional, from what systems measured here cost, as `scenario run --parallel auto`
reasons), runs the scenario as a whole isolated system on whichever node Ray gives it, and
returns its record, with its run directory packed when the campaign keeps it. Ray retries a task
whose worker or node dies; the driver stores each result as it arrives (`store.Store`), so a
killed driver loses nothing and `--resume` runs only what has no result."""

from __future__ import annotations

import io
import logging
import math
import os
import shutil
import signal
import socket
import tarfile
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import ray
from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

from abyss.common.errors import AbyssError, ConfigError
from abyss.validation.campaign.plan import RunSpec
from abyss.validation.campaign.store import RunRecord, Store, record_of
from abyss.validation.campaign.version import abyss_version
from abyss.validation.scenario import capacity
from abyss.validation.scenario.runner import run_scenario

SCRATCH_PREFIX = "abyss-run-"  # a run's scratch folder: this, its worker's pid, a dash
PROGRESS_WALL_S = 10.0  # a line of progress at least this often
TASK_RETRIES = 3  # a run whose worker or node dies is run again, this many times at most
CONNECT_TIMEOUT_S = 30.0
ADDRESS_FIX = (
    "start one with `ray start --head` on the head node and give its GCS address (HOST:6379), "
    "or leave --address out for a local Ray"
)


class VersionMismatch(AbyssError):
    """A node runs other abyss code than the driver."""


@dataclass(frozen=True)
class Outcome:
    """What a run's task returns: its record, and its run directory as a gzipped tar where kept."""

    record: RunRecord
    archive: bytes


def node_name() -> str:
    """This node as a person finds it: host name and the address Ray knows it by."""
    return f"{socket.gethostname()}/{ray.util.get_node_ip_address()}"


def _pack(directory: Path) -> bytes:
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w:gz", compresslevel=3) as tar:
        tar.add(directory, arcname=".")
    return buffer.getvalue()


def run_one(spec: RunSpec, keep: str, driver_version: str) -> Outcome:
    """A run on this node (a Ray task's body; the scenario runs as `scenario run` runs it)."""
    here = abyss_version()
    if here != driver_version:
        raise VersionMismatch(f"node {node_name()} runs abyss {here}, the driver {driver_version}")
    # Ray's workers block SIGINT, and a blocked mask is inherited: `abyss up` could then never
    # stop its stations (they stop on SIGINT). Unblocked for the run, as in a shell.
    blocked = signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    try:
        sweep_scratch()
        with tempfile.TemporaryDirectory(prefix=f"{SCRATCH_PREFIX}{os.getpid()}-") as scratch:
            return _run(spec, keep, Path(scratch))
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, blocked)


def sweep_scratch() -> list[Path]:
    """Remove the scratch folders of runs whose worker is gone from this node (killed mid-run: a
    node lost, a shard stopped, Ray's retry) and so never removed its own; those removed."""
    swept = []
    for scratch in Path(tempfile.gettempdir()).glob(f"{SCRATCH_PREFIX}*-*"):
        pid = scratch.name.removeprefix(SCRATCH_PREFIX).split("-", 1)[0]
        if pid.isdigit() and not _alive(int(pid)):
            shutil.rmtree(scratch, ignore_errors=True)
            swept.append(scratch)
    return swept


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's
        return True
    return True


def _run(spec: RunSpec, keep: str, scratch: Path) -> Outcome:
    result = run_scenario(spec.scenario, scratch / spec.run_id, 0, lambda _: None)
    kept = keep == "all" or (keep == "failing" and not result.passed)
    archive = _pack(result.out_dir) if kept else b""
    return Outcome(record_of(spec, result, node_name(), f"runs/{spec.run_id}" if kept else ""), archive)


def _version_of_node() -> tuple[str, str]:
    return node_name(), abyss_version()


def connect(address: str | None) -> None:
    """Ray: a local instance on this machine's cores, or the cluster at `address`."""
    logging.getLogger("ray").setLevel(logging.WARNING)
    if address is None:
        ray.init(
            address="local",
            num_cpus=max(1, math.floor(capacity.available_cores())),
            include_dashboard=False,
            log_to_driver=False,
            logging_level=logging.WARNING,
        )
        return
    try:
        ray.init(address=address, log_to_driver=False, logging_level=logging.WARNING)
    except (ConnectionError, RuntimeError, ValueError) as exc:
        raise ConfigError(
            "--address", f"no Ray cluster answers at {address} ({str(exc).splitlines()[0]}): {ADDRESS_FIX}"
        ) from None


def check_address(address: str | None) -> None:
    """ConfigError with the fix, at once, where nothing answers at a Ray address (Ray itself would
    retry for minutes)."""
    if address is not None and (why := unanswered(address)):
        raise ConfigError("--address", f"no Ray cluster answers at {address} ({why}): {ADDRESS_FIX}")


def unanswered(address: str) -> str:
    """Why nothing takes a TCP connection at a Ray address (`HOST:PORT`, `ray://HOST:PORT`; the
    GCS's 6379 where the port is left out), or '' where something does (`auto`: Ray looks)."""
    if address == "auto":
        return ""
    host, _, port = address.removeprefix("ray://").rpartition(":")
    if not host or not port.isdigit():
        host, port = address.removeprefix("ray://"), "6379"
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=CONNECT_TIMEOUT_S / 3):
            return ""
    except OSError as exc:
        return exc.strerror or str(exc)


def check_versions() -> list[str]:
    """Every live node's abyss against the driver's: the nodes, or VersionMismatch naming both."""
    mine = abyss_version()
    probe = ray.remote(num_cpus=0)(_version_of_node)
    refs = [
        probe.options(scheduling_strategy=NodeAffinitySchedulingStrategy(n["NodeID"], soft=False)).remote()
        for n in ray.nodes()
        if n["Alive"]
    ]
    nodes = ray.get(refs, timeout=CONNECT_TIMEOUT_S * 4)
    for name, theirs in nodes:
        if theirs != mine:
            raise VersionMismatch(
                f"node {name} runs abyss {theirs}, this driver {mine}: install the same abyss on every "
                "node (the same commit, or the same image)"
            )
    return sorted(name for name, _ in nodes)


def task_cores(runs: list[RunSpec]) -> float:
    """The cores one run asks Ray for: a system's measured cost at the runs' speed, over the
    headroom `--parallel auto` keeps (so a local campaign runs as many at once as it would)."""
    speeds = {r.scenario.time.speed_factor if r.scenario.time.simulated else 1.0 for r in runs}
    speed = max(speeds, default=1.0)
    per_system, _ = capacity.measured_cores()
    cores = per_system * speed if math.isfinite(speed) else 1.0
    return round(cores / capacity.HEADROOM, 2)


def gather(outcome: Outcome, store: Store) -> None:
    """A finished run into the campaign directory: its kept directory unpacked (atomically, by a
    rename), then its record. A directory that cannot be written (a full disk) leaves no record,
    so that `--resume` runs it again."""
    if outcome.archive:
        final = store.dir / outcome.record.kept
        partial = final.with_name(final.name + ".partial")
        shutil.rmtree(partial, ignore_errors=True)
        partial.mkdir(parents=True)
        with tarfile.open(fileobj=io.BytesIO(outcome.archive), mode="r:gz") as tar:
            tar.extractall(partial, filter="data")
        shutil.rmtree(final, ignore_errors=True)
        os.replace(partial, final)
    store.add(outcome.record)


@dataclass
class Progress:
    """Runs done, failed and running, the nodes and cores in use, and the time left."""

    total: int
    cores_per_run: float
    say: Callable[[str], None]
    done: int = 0
    failed: int = 0
    started_s: float = field(default_factory=time.monotonic)
    last_s: float = 0.0

    def line(self, pending: int) -> str:
        """`pending`: the runs submitted without a result, running or queued (Ray's CPU in use
        tells how many run)."""
        elapsed_s = time.monotonic() - self.started_s
        if self.done == self.total:
            return f"{self.done}/{self.total} runs done ({self.failed} failed) in {elapsed_s / 60:.1f} min"
        left_min = elapsed_s / self.done * (self.total - self.done) / 60 if self.done else None
        nodes = sum(1 for n in ray.nodes() if n["Alive"])
        total_cores = ray.cluster_resources().get("CPU", 0.0)
        used_cores = max(0.0, total_cores - ray.available_resources().get("CPU", 0.0))
        running = min(pending, round(used_cores / self.cores_per_run)) if self.cores_per_run else pending
        return (
            f"{self.done}/{self.total} runs done ({self.failed} failed), {running} running on {nodes} "
            f"node{'s' * (nodes != 1)} ({pending - running} queued), {used_cores:.1f}/{total_cores:g} "
            "cores in use; "
            + (f"~{left_min:.1f} min left" if left_min is not None else "time left unknown yet")
        )

    def tick(self, pending: int, force: bool = False) -> None:
        now_s = time.monotonic()
        if force or now_s - self.last_s >= PROGRESS_WALL_S:
            self.last_s = now_s
            self.say(self.line(pending))


def execute(todo: list[RunSpec], keep: str, store: Store, say: Callable[[str], None]) -> list[str]:
    """Every run in `todo` through Ray, each stored as it arrives; the runs that got no result
    (their task failed past its retries), each with why."""
    task = ray.remote(max_retries=TASK_RETRIES, retry_exceptions=False)(run_one)
    cores = task_cores(todo)
    version = abyss_version()
    pending = {task.options(num_cpus=cores).remote(spec, keep, version): spec for spec in todo}
    progress = Progress(len(todo), cores, say)
    lost: list[str] = []
    while pending:
        ready, _ = ray.wait(list(pending), num_returns=1, timeout=PROGRESS_WALL_S)
        for ref in ready:
            spec = pending.pop(ref)
            try:
                outcome: Outcome = ray.get(ref)
            except ray.exceptions.RayError as exc:
                cause = exc.cause if isinstance(exc, ray.exceptions.RayTaskError) else exc
                if isinstance(cause, VersionMismatch):
                    ray.cancel(list(pending), force=True)
                    raise cause from None
                lost.append(
                    f"{spec.run_id} ({spec.scenario_name}, {spec.variant.name}, seed {spec.seed}): {cause}"
                )
                continue
            try:
                gather(outcome, store)
            except OSError as exc:
                lost.append(f"{spec.run_id}: its directory could not be kept ({exc}); --resume runs it again")
                continue
            progress.done += 1
            progress.failed += not outcome.record.passed
            say(
                f"{'PASS' if outcome.record.passed else 'FAIL'} {spec.scenario_name} [{spec.variant.name}] "
                f"seed {spec.seed} on {outcome.record.node} in {outcome.record.wall_s:.0f} s"
                + (
                    f": {outcome.record.error or '; '.join(outcome.record.wrong)}"
                    if not outcome.record.passed
                    else ""
                )
            )
        progress.tick(len(pending), force=bool(ready) and not pending)
    return lost
