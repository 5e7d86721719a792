"""A campaign from its file to its report: the plan (a shard of it), the store in the campaign
directory (refusing one that holds another campaign, going on in one with `--resume`), the runs
without a result through Ray, then the report and the exit code."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

import ray

from abyss.common.errors import ConfigError
from abyss.validation.campaign import execute
from abyss.validation.campaign.plan import RunSpec, plan, shard
from abyss.validation.campaign.report import Report, build_report, counts_text
from abyss.validation.campaign.spec import Campaign
from abyss.validation.campaign.store import PLAN_FILE, Store
from abyss.validation.campaign.version import abyss_version


def run_campaign(
    campaign: Campaign,
    out: Path,
    address: str | None,
    resume: bool,
    slice_: tuple[int, int] | None,
    say: Callable[[str], None],
) -> int:
    """Run what has no result yet, report, and exit 0 when every scenario and variant reached
    its minimum pass rate (1: one did not; 4: runs were lost and `--resume` goes on)."""
    execute.check_address(address)
    whole = plan(campaign)
    runs = shard(whole, *slice_) if slice_ is not None else whole
    store = Store(out)
    _open_store(store, campaign, whole, out, resume, slice_)
    mine = {r.run_id for r in runs}
    have = {run_id: r for run_id, r in store.records().items() if run_id in mine}
    todo = [r for r in runs if r.run_id not in have]
    say(
        f"campaign {campaign.name}: {len(runs)} runs ({len({r.scenario_name for r in runs})} scenarios, "
        f"{len({r.variant.name for r in runs})} variants, {len(campaign.seeds)} seeds)"
        + (f", shard {slice_[0]}/{slice_[1]}" if slice_ else "")
        + (f"; {len(have)} have results, {len(todo)} to run" if resume else "")
        + f"; directory {out}"
    )
    lost: list[str] = []
    started_s = time.monotonic()
    if todo:
        execute.connect(address)
        try:
            nodes = execute.check_versions()
            say(
                f"Ray: {len(nodes)} node{'s' * (len(nodes) != 1)} ({', '.join(nodes)}), "
                f"{ray.cluster_resources().get('CPU', 0):g} cores; each run asks for "
                f"{execute.task_cores(todo):g}"
            )
            lost = execute.execute(todo, campaign.keep, store, say)
        except KeyboardInterrupt:  # Ctrl-C: what is stored stays, the runs in flight are let go
            say(
                f"interrupted: {len(store.records())} results kept in {out}; `abyss campaign run "
                f"{campaign.path} --out {out} --resume` goes on"
            )
            return 130
        finally:
            ray.shutdown()
    store.add_wall(time.monotonic() - started_s)
    for line in lost:
        say(f"LOST {line}")
    report = build_report(runs, store.records(), out, campaign.min_rate, store.wall_s(), campaign.name)
    code = conclude(report, out, say)
    if lost:
        say(
            f"{len(lost)} runs got no result: `abyss campaign run {campaign.path} --out {out} "
            "--resume` runs them"
        )
        return 4
    return code


def _open_store(
    store: Store,
    campaign: Campaign,
    whole: list[RunSpec],
    out: Path,
    resume: bool,
    slice_: tuple[int, int] | None,
) -> None:
    """A new campaign's plan written, or a resumed one's checked against the file's: a directory
    that holds another campaign is refused, and so is `--resume` where there is none."""
    planned = (out / PLAN_FILE).exists()
    if planned and not resume:
        raise ConfigError(
            "--out", f"{out} holds a campaign already: --resume goes on there, or give another --out"
        )
    if resume and not planned:
        raise ConfigError("--resume", f"{out} holds no campaign to go on with")
    if resume:
        store.check_plan(whole, abyss_version(), slice_)
    else:
        store.write_plan(campaign, whole, abyss_version(), slice_)


def conclude(report: Report, out: Path, say: Callable[[str], None]) -> int:
    """The report's lines a person reads first, and the exit code."""
    for case in report.cases:
        say(f"{'ok  ' if case.ok else 'FAIL'} {case.scenario} [{case.variant}]: {counts_text(case)}")
    say(f"report {out / 'report.md'}, JUnit {out / 'junit.xml'}")
    return 0 if report.passed() else 1
