"""What a scenario run leaves for people and CI servers: JUnit XML (one test case per
scenario, a failure per assertion that did not hold) and a Markdown report with every
assertion's verdict, the run's figures, its plots and its recording."""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from pathlib import Path

from abyss.validation.plot import FIGURES
from abyss.validation.scenario.runner import Result


def junit(results: list[Result], path: Path) -> None:
    suite = ET.Element(
        "testsuite",
        name="abyss scenarios",
        tests=str(len(results)),
        failures=str(sum(not r.passed for r in results)),
        time=f"{sum(r.wall_s for r in results):.1f}",
    )
    for r in results:
        case = ET.SubElement(
            suite,
            "testcase",
            classname=f"scenarios.{r.scenario.use}",
            name=r.scenario.name,
            time=f"{r.wall_s:.1f}",
        )
        properties = ET.SubElement(case, "properties")
        ET.SubElement(properties, "property", name="verdict", value=r.outcome)
        if r.error:
            ET.SubElement(case, "error", message=r.why_failed).text = r.error
        elif not r.passed:
            failure = ET.SubElement(case, "failure", message=r.why_failed)
            failure.text = "\n".join(map(str, r.verdicts))
        ET.SubElement(case, "system-out").text = f"verdict: {r.outcome}\nrun directory: {r.out_dir}"
    path.parent.mkdir(parents=True, exist_ok=True)
    ET.ElementTree(suite).write(path, encoding="utf-8", xml_declaration=True)


def markdown(results: list[Result], directory: Path) -> Path:
    directory.mkdir(parents=True, exist_ok=True)
    lines = [
        "# abyss scenario report",
        "",
        "| scenario | use | result | verdict | assertions held | wall s |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for r in results:
        held = f"{sum(v.passed for v in r.verdicts)}/{len(r.verdicts)}"
        lines.append(
            f"| [{r.scenario.name}](#{r.scenario.name}) | {r.scenario.use} | "
            f"{'PASS' if r.passed else 'FAIL'} | {r.outcome} | {held} | {r.wall_s:.0f} |"
        )
    for r in results:
        rel = Path(os.path.relpath(r.out_dir, directory))
        lines += [
            "",
            f"## {r.scenario.name}",
            "",
            r.scenario.description,
            "",
            f"Result: **{'PASS' if r.passed else 'FAIL'}**, verdict **{r.outcome}**"
            + (
                f" (expected to fail: {', '.join(r.scenario.expect_failed)})"
                if r.scenario.expect_failed
                else ""
            )
            + f"; run directory `{rel}`, recording [{rel}/onshore.rrd]({rel}/onshore.rrd).",
            "",
        ]
        if r.error:
            lines += ["```", r.error, "```"]
        lines += ["| assertion | held | figure |", "| --- | --- | --- |"]
        lines += [
            f"| `{v.assertion.describe()}` | {'yes' if v.passed else 'no'} | {v.detail} |" for v in r.verdicts
        ]
        lines += [""] + [
            f"![{name}]({rel}/{name}.png)" for name in FIGURES if (r.out_dir / f"{name}.png").exists()
        ]
    path = directory / "report.md"
    path.write_text("\n".join(lines) + "\n")
    return path
