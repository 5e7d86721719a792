"""A campaign's report: per scenario and variant the runs, the passes, the pass rate with its
95 % Wilson interval, "flaky" where it is neither 0 nor 1, how often each assertion came out
wrong and the failing runs (with how to replay them); per value of each matrix axis the pass
rate over the others (the margins: which station's kill, which moment); per variant the figures' distributions
(plots); a heat map of the pass rate over the matrix's first two axes; JUnit with one test case
per scenario and variant; and the campaign's cost. Deterministic: the same records give the
same report.json (the cost, which holds wall times, aside), however many shards made them."""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import xml.etree.ElementTree as ET
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from abyss.common.errors import ConfigError
from abyss.validation.campaign import figures as plots
from abyss.validation.campaign.case import Case
from abyss.validation.campaign.plan import RunSpec
from abyss.validation.campaign.stats import flaky, wilson
from abyss.validation.campaign.store import RunRecord, Store

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Report:
    name: str
    out_dir: Path
    axes: tuple[str, ...]  # the matrix's keys
    cases: tuple[Case, ...]
    cost: dict[str, Any]

    def passed(self) -> bool:
        """Every scenario and variant at or above its min pass rate."""
        return all(c.ok for c in self.cases)

    def margins(self) -> dict[str, list[dict[str, Any]]]:
        """Per matrix axis, per value (in the plan's order): the runs with that value, over every
        other axis, scenario and seed: passes, pass rate and its 95 % Wilson interval."""
        out: dict[str, list[dict[str, Any]]] = {}
        for axis in self.axes:
            tally: dict[str, list[int]] = {}
            for c in self.cases:
                counts = tally.setdefault(json.dumps(c.values[axis]), [0, 0])
                counts[0] += c.passes
                counts[1] += c.runs
            out[axis] = [
                {
                    "value": json.loads(value),
                    "runs": runs,
                    "passes": passes,
                    "pass_rate": passes / runs if runs else None,
                    "wilson_95": list(wilson(passes, runs)),
                }
                for value, (passes, runs) in tally.items()
            ]
        return out

    def data(self) -> dict[str, Any]:
        """report.json's content: everything but "cost" is the same for the same records."""
        return {
            "campaign": self.name,
            "passed": self.passed(),
            "axes": list(self.axes),
            "planned": sum(c.planned for c in self.cases),
            "runs": sum(c.runs for c in self.cases),
            "pending": sum(c.planned - c.runs for c in self.cases),
            "cases": [c.data() for c in self.cases],
            "margins": self.margins(),
            "cost": self.cost,
        }


def cases_of(
    plan_runs: list[RunSpec], records: Mapping[str, RunRecord], min_rate: Callable[[str], float]
) -> tuple[Case, ...]:
    """The plan's runs grouped by scenario and variant, in plan order, each with its records by seed."""
    groups: dict[tuple[str, str], list[RunSpec]] = {}
    for run in plan_runs:
        groups.setdefault((run.scenario_name, run.variant.name), []).append(run)
    cases = []
    for (scenario, variant), runs in groups.items():
        found = sorted((records[r.run_id] for r in runs if r.run_id in records), key=lambda r: r.seed)
        cases.append(
            Case(
                scenario=scenario,
                variant=variant,
                values=runs[0].variant.as_dict(),
                planned=len(runs),
                min_rate=min_rate(scenario),
                records=tuple(found),
                why_not_replayable={r.run_id: r.why_not_replayable for r in runs if not r.replayable},
            )
        )
    return tuple(cases)


def cost_of(records: list[RunRecord], wall_s: float) -> dict[str, Any]:
    """What the campaign cost: core-hours (the stations' CPU), its wall time [s] and the simulated
    seconds it made per wall second; and which nodes ran how many runs."""
    sim_s = sum(r.sim_s for r in records)
    return {
        "core_hours": sum(r.core_s for r in records) / 3600.0,
        "wall_s": wall_s,
        "runs_wall_s": sum(r.wall_s for r in records),
        "sim_s": sim_s,
        "sim_s_per_wall_s": sim_s / wall_s if wall_s > 0 else None,
        "nodes": dict(sorted(Counter(r.node for r in records).items())),
    }


def build_report(
    plan_runs: list[RunSpec],
    records: Mapping[str, RunRecord],
    out_dir: Path,
    min_rate: Callable[[str], float],
    wall_s: float = 0.0,
    name: str = "campaign",
) -> Report:
    """The report of `records` against the planned runs, written to `out_dir` (report.md,
    report.json, junit.xml, plots/*.png); `wall_s` is the campaign's wall time [s]."""
    cases = cases_of(plan_runs, records, min_rate)
    planned = {r.run_id for r in plan_runs}
    stray = [run_id for run_id in records if run_id not in planned]
    if stray:
        log.warning("%d records of runs not in the plan ignored, e.g. %s", len(stray), stray[0])
    axes = tuple(k for k, _ in plan_runs[0].variant.values) if plan_runs else ()
    ran = [r for c in cases for r in c.records]
    report = Report(name, out_dir, axes, cases, cost_of(ran, wall_s))
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "report.json").write_text(json.dumps(report.data(), indent=1) + "\n")
    junit(report, out_dir / "junit.xml")
    pictures = plots.plot_all(cases, axes, out_dir / "plots")
    markdown(report, out_dir / "report.md", pictures)
    return report


def percent(rate: float | None) -> str:
    return "-" if rate is None else f"{rate * 100:.0f} %"


def counts_text(case: Case) -> str:
    low, high = wilson(case.passes, case.runs)
    return (
        f"{case.passes}/{case.runs} passed ({percent(case.rate)}, 95 % interval "
        f"{percent(low)} to {percent(high)}), min pass rate {percent(case.min_rate)}"
    )


def junit(report: Report, path: Path) -> None:
    """One test case per scenario and variant, failed under its min pass rate, skipped with no result."""
    suite = ET.Element(
        "testsuite",
        name=f"campaign {report.name}",
        tests=str(len(report.cases)),
        failures=str(sum(c.runs > 0 and not c.ok for c in report.cases)),
        skipped=str(sum(c.runs == 0 for c in report.cases)),
        time=f"{report.cost['wall_s']:.1f}",
    )
    for c in report.cases:
        case = ET.SubElement(
            suite,
            "testcase",
            classname=f"campaign.{c.scenario}",
            name=c.variant,
            time=f"{sum(r.wall_s for r in c.records):.1f}",
        )
        properties = ET.SubElement(case, "properties")
        low, high = wilson(c.passes, c.runs)
        for key, value in (
            ("runs", c.runs),
            ("passes", c.passes),
            ("wilson_low", low),
            ("wilson_high", high),
        ):
            ET.SubElement(properties, "property", name=key, value=f"{value:g}")
        if c.runs == 0:
            ET.SubElement(case, "skipped", message=f"no result yet: {c.planned} runs pending")
        elif not c.ok:
            failure = ET.SubElement(case, "failure", message=counts_text(c))
            failure.text = "\n".join(f"{r['run_id']} seed {r['seed']}: {r['why']}" for r in c.failing())
        ET.SubElement(case, "system-out").text = counts_text(c) + (
            "; flaky" if flaky(c.passes, c.runs) else ""
        )
    path.parent.mkdir(parents=True, exist_ok=True)
    ET.ElementTree(suite).write(path, encoding="utf-8", xml_declaration=True)


def _case_lines(c: Case, out_dir: Path) -> list[str]:
    counts = counts_text(c) + ("; **flaky**" if flaky(c.passes, c.runs) else "")
    if c.planned > c.runs:
        counts += f"; {c.planned - c.runs} runs pending"
    lines = ["", f"### {c.scenario}: {c.variant}", "", counts]
    failures = c.failures()
    if failures:
        lines += ["", "| assertion | runs it failed in |", "| --- | --- |"]
        lines += [f"| `{a}` | {n} |" for a, n in failures.items()]
    lines += [""] if c.failing() else []
    for r in c.failing():
        how = (
            f"`abyss campaign replay {out_dir} {r['run_id']}`"
            if r["replayable"]
            else f"replays only statistically ({r['why_not_replayable']})"
        )
        lines.append(f"- `{r['run_id']}` seed {r['seed']}: {r['why'] or r['outcome']}; {how}")
    return lines


def markdown(report: Report, path: Path, pictures: list[Path]) -> None:
    verdict = "PASS" if report.passed() else "FAIL"
    data = report.data()
    lines = [
        f"# Campaign {report.name}: {verdict}",
        "",
        f"{data['runs']} runs of {data['planned']} planned ({data['pending']} pending); "
        f"{sum(c.ok for c in report.cases)} of {len(report.cases)} scenario-variants at or above "
        "their min pass rate.",
        "",
        "| scenario | variant | runs | passes | pass rate | 95 % interval | min | |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for c in report.cases:
        low, high = wilson(c.passes, c.runs)
        mark = ("ok" if c.ok else "**FAIL**" if c.runs else "pending") + (
            ", flaky" if flaky(c.passes, c.runs) else ""
        )
        lines.append(
            f"| {c.scenario} | {c.variant} | {c.runs} | {c.passes} | {percent(c.rate)} | "
            f"{percent(low)} to {percent(high)} | {percent(c.min_rate)} | {mark} |"
        )
    for axis, rows in (data["margins"] if len(report.axes) > 1 else {}).items():
        lines += ["", f"## By `{axis}`", "", "| value | runs | passes | pass rate | 95 % interval |"]
        lines += ["| --- | --- | --- | --- | --- |"]
        for row in rows:
            low, high = row["wilson_95"]
            lines.append(
                f"| {row['value']} | {row['runs']} | {row['passes']} | {percent(row['pass_rate'])} | "
                f"{percent(low)} to {percent(high)} |"
            )
    lines += ["", "## Scenarios and variants"]
    for c in report.cases:
        lines += _case_lines(c, report.out_dir)
    if pictures:
        lines += ["", "## Figures", ""]
        lines += [f"![{p.stem}]({os.path.relpath(p, path.parent)})" for p in pictures]
    cost = report.cost
    lines += [
        "",
        "## Cost",
        "",
        f"{cost['core_hours']:.3g} core-hours; {cost['wall_s']:.0f} s of wall time; "
        f"{cost['sim_s']:.0f} s simulated"
        + (f", {cost['sim_s_per_wall_s']:.2f} simulated s per wall s" if cost["sim_s_per_wall_s"] else "")
        + "; nodes: "
        + (", ".join(f"{node} ({n} runs)" for node, n in cost["nodes"].items()) or "none"),
    ]
    path.write_text("\n".join(lines) + "\n")


def merge(dirs: list[Path], out: Path) -> Report:
    """One report of the shards' campaign directories `dirs` (the same campaign and abyss), written
    with the union of their records (and their plan, whole) to `out`; their wall times summed."""
    if not dirs:
        raise ConfigError("DIR", "at least one campaign directory to merge")
    plans = [(d, Store(d).read_plan()) for d in dirs]
    first_dir, first = plans[0]
    for d, p in plans[1:]:
        if (p.campaign, p.version) != (first.campaign, first.version):
            raise ConfigError(
                "DIR",
                f"{d} holds campaign {p.campaign} on abyss {p.version}, {first_dir} campaign "
                f"{first.campaign} on abyss {first.version}: only shards of one campaign merge",
            )
        if [r.run_id for r in p.all_runs] != [r.run_id for r in first.all_runs]:
            raise ConfigError(
                "DIR", f"{d} and {first_dir} planned campaign {p.campaign} differently (its file changed?)"
            )
    merged = Store(out)
    if (out / "results.jsonl").exists() or any(out.resolve() == d.resolve() for d in dirs):
        raise ConfigError("--out", f"{out} holds a campaign already: merge into a new directory")
    merged.write_plan_file(dataclasses.replace(first, shard=""))
    records: dict[str, RunRecord] = {}
    for d in dirs:
        for run_id, record in Store(d).records().items():
            if run_id not in records:
                kept = os.path.relpath(d / record.kept, out) if record.kept else ""
                records[run_id] = RunRecord.from_json({**record.to_json(), "kept": kept})
                merged.add(records[run_id])
    wall_s = sum(Store(d).wall_s() for d in dirs)
    merged.add_wall(wall_s)
    return build_report(list(first.all_runs), records, out, first.min_rate, wall_s, first.campaign)
