"""The kill campaign's figures (issue #39): from a finished `abyss campaign run campaigns/kills.toml`
directory, the pass rate per station killed with its 95 % Wilson interval, and per phase of the
mission in which the kill landed; and every run in which an intervention was reported done while
the simulation's truth had the part out of tolerance (a false "done"). A run that did not complete
(the harness's error, not the system's verdict) is listed and left out of the rates.

The phase a kill landed in comes from a run of the same seed without the kill: in lockstep a run
is the same, bit for bit, up to its first event, so the no-kill run's onboard states
(control.csv) at the kill's moment are the killed run's. Make them with
`abyss scenario run FILE... --time lockstep` on the kill scenario without its event, one file per
seed (`[config] seed`), each file's name ending in its seed (`seed0.toml`, ...).

Run: .venv/bin/python bench/kills.py CAMPAIGN_DIR TIMELINES_REPORT_DIR. Prints tables; asserts
nothing."""

from __future__ import annotations

import argparse
import csv
import json
import re
from collections import defaultdict
from pathlib import Path

from abyss.interface.messages import IDLE_PHASES
from abyss.validation.campaign.stats import wilson

AFTER = "after the mission's end"


def timelines(report_dir: Path) -> dict[int, list[dict[str, str]]]:
    """Per seed, the no-kill run's onboard states (control.csv rows)."""
    out = {}
    for run in sorted((report_dir / "runs").iterdir()):
        seed = re.search(r"(\d+)$", run.name)
        if seed is not None and (run / "control.csv").exists():
            with (run / "control.csv").open() as f:
                out[int(seed.group(1))] = list(csv.DictReader(f))
    return out


def phase_at(rows: list[dict[str, str]], t_s: float) -> str:
    """What the mission was doing at `t_s`: flying its waypoints, an intervention's phase, or over."""
    if t_s > float(rows[-1]["sim_time_s"]):
        return AFTER
    row = next(r for r in rows if float(r["sim_time_s"]) >= t_s)
    phase, target = row["intervention_phase"], row["intervention_target"]
    if phase in IDLE_PHASES:
        return "waypoints" if not target else f"between ({target} {phase or 'next'})"
    return f"{target} {phase}"


def table(title: str, groups: dict[str, list[bool]]) -> None:
    print(f"\n{title}\n| | runs | passes | pass rate | 95 % interval |\n| --- | --- | --- | --- | --- |")
    for name, passed in groups.items():
        low, high, rate = *wilson(sum(passed), len(passed)), sum(passed) / len(passed)
        print(f"| {name} | {len(passed)} | {sum(passed)} | {rate:.2f} | {low:.2f} to {high:.2f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("campaign", type=Path)
    parser.add_argument("timelines", type=Path)
    args = parser.parse_args()
    results = [
        json.loads(line) for line in (args.campaign / "results.jsonl").read_text().splitlines() if line
    ]
    lines = timelines(args.timelines)
    by_station: dict[str, list[bool]] = defaultdict(list)
    by_phase: dict[str, list[bool]] = defaultdict(list)
    not_landed, false_done, unfinished = [], [], []
    for r in sorted(
        results, key=lambda r: (r["values"]["events[0].station"], r["values"]["events[0].at_s"], r["seed"])
    ):
        station, at_s = r["values"]["events[0].station"], r["values"]["events[0].at_s"]
        phase = phase_at(lines[r["seed"]], at_s)
        if phase == AFTER:
            not_landed.append(f"{station} at {at_s} s seed {r['seed']}")
            continue
        if r["error"]:  # the run did not complete: no verdict on the system (rerun it: --resume)
            unfinished.append(f"{station} at {at_s} s seed {r['seed']}: {r['error']}")
            continue
        by_station[station].append(r["passed"])
        by_phase[phase].append(r["passed"])
        for v in r["verdicts"]:
            if v["kind"] == "intervention" and not v["passed"] and re.match(r"\w+ done;", v["detail"]):
                false_done.append(f"{station} at {at_s} s seed {r['seed']}: {v['detail']}")
        if not r["passed"]:
            why = "; ".join(v["detail"] for v in r["verdicts"] if not v["passed"]) or r["error"]
            print(f"FAIL {station} at {at_s} s ({phase}) seed {r['seed']}: {why}")
    landed = [p for v in by_station.values() for p in v]
    print(f"\n{len(results)} runs, {len(landed)} with the kill landed before the mission's end")
    table("Per station killed", dict(sorted(by_station.items())))
    table("Per phase the kill landed in", dict(sorted(by_phase.items())))
    table("All", {"every station": landed})
    print(f"\nNot landed (the mission was done first): {len(not_landed)}")
    print(f"Did not complete (no verdict; left out of the rates): {len(unfinished)}")
    for line in unfinished:
        print("  " + line)
    print(f"False 'done' (onboard said done, the truth out of tolerance): {len(false_done)}")
    for line in false_done:
        print("  " + line)


if __name__ == "__main__":
    main()
