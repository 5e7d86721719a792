"""A campaign directory: its plan (`plan.json`, written once), its results (`results.jsonl`,
one record per finished run, appended and synced to disk line by line so that a killed driver
loses at most the line it was writing), the wall time of each session that ran it
(`sessions.jsonl`) and the run directories it keeps (`runs/<run_id>/`)."""

from __future__ import annotations

import csv
import dataclasses
import json
import logging
import math
import os
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from abyss.common.errors import ConfigError
from abyss.launch.control_record import CONTROL_FILE
from abyss.launch.verdict import read_json
from abyss.validation.campaign.plan import RunSpec, shard
from abyss.validation.campaign.version import abyss_version

if TYPE_CHECKING:
    from abyss.validation.campaign.spec import Campaign
    from abyss.validation.scenario.runner import Result

log = logging.getLogger(__name__)

PLAN_FILE = "plan.json"
RESULTS_FILE = "results.jsonl"
SESSIONS_FILE = "sessions.jsonl"
RUNS_DIR = "runs"
FIGURES = (  # name [unit]: what it is, in the order reports show them (interventions after)
    "mission_s",  # [s since all stations were up] when onboard said the mission was done
    "vehicle_error_m",  # [m] onboard's final vehicle position error
    "ee_error_m",  # [m] the final end-effector position error
    "ee_error_deg",  # [deg] the final end-effector orientation error
    "failsafe_entry_s",  # [s, the simulation's clock] when onboard first reported a failsafe
    "scene_cells",  # occupied cells of shore's scene at the end
    "cores",  # the stations' CPU seconds over the run's wall seconds
    "sim_s",  # [s] simulated time
)


@dataclass
class RunRecord:
    """One finished run, as the store keeps it."""

    run_id: str
    scenario: str
    variant: str  # the variant's name
    values: dict[str, Any]  # the variant's values by matrix key
    seed: int
    version: str
    time: str  # the time source it ran on
    replayable: bool
    passed: bool
    outcome: str
    error: str  # why the run itself did not complete; '' if it did
    verdicts: list[dict[str, Any]]  # {"assertion": describe, "kind", "passed", "detail"}
    wrong: list[str]  # describes of the assertions that did not come out as expected
    figures: dict[str, float | None]
    wall_s: float
    sim_s: float
    core_s: float  # the stations' CPU [s]
    node: str  # the host that ran it
    kept: str  # its directory relative to the campaign directory, or ''

    def to_json(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> RunRecord:
        return cls(**{f.name: data[f.name] for f in dataclasses.fields(cls)})


def failsafe_entry_s(control_csv: Path) -> float | None:
    """When onboard first reported a failsafe [s, the simulation's clock], from a run's control
    record; None if it never did or there is no record."""
    try:
        with control_csv.open(newline="") as f:
            for row in csv.DictReader(f):
                if row.get("failsafe"):
                    return float(row["sim_time_s"])
    except (OSError, ValueError, csv.Error):
        return None
    return None


def _number(value: Any) -> float | None:
    if isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value):
        return float(value)
    return None


def figures(summary: dict[str, Any], control_csv: Path | None = None) -> dict[str, float | None]:
    """The figures that matter of one run (FIGURES, then `intervention_<part>_error_deg`: each
    worked part's final angle off its target on the simulation's truth [deg]), from its
    `summary.json` and, for the failsafe's entry, its control record; None where the run has none."""
    control = summary.get("control") or {}
    scene = summary.get("scene") or {}
    stations = summary.get("stations") or {}
    cpu_s = [s["cpu"]["cpu_s"] for s in stations.values() if isinstance(s.get("cpu"), dict)]
    wall_s = _number(summary.get("wall_s"))
    timing = summary.get("time") or {}
    simulation = summary.get("simulation") or {}
    found: dict[str, float | None] = {
        "mission_s": _number(summary.get("mission_done_s")),
        "vehicle_error_m": _number(control.get("position_error_m")),
        "ee_error_m": _number(control.get("ee_position_error_m")),
        "ee_error_deg": _number(control.get("ee_orientation_error_deg")),
        "failsafe_entry_s": failsafe_entry_s(control_csv) if control_csv is not None else None,
        "scene_cells": _number(scene.get("occupied_cells")),
        "cores": sum(cpu_s) / wall_s if cpu_s and wall_s else None,
        "sim_s": _number(timing.get("sim_s", simulation.get("sim_time_s"))),
    }
    for judged in summary.get("interventions") or []:
        truth, target = _number(judged.get("truth_deg")), _number(judged.get("target_deg"))
        error = None if truth is None or target is None else abs(truth - target)
        found[f"intervention_{judged['part']}_error_deg"] = error
    return found


def record_of(spec: RunSpec, result: Result, node: str, kept: str) -> RunRecord:
    """The record of a finished run: its verdicts and its figures (read from its directory)."""
    summary = read_json(result.out_dir / "summary.json")
    found = figures(summary, result.out_dir / CONTROL_FILE)
    stations = summary.get("stations") or {}
    return RunRecord(
        run_id=spec.run_id,
        scenario=spec.scenario_name,
        variant=spec.variant.name,
        values=spec.variant.as_dict(),
        seed=spec.seed,
        version=abyss_version(),
        time=spec.time,
        replayable=spec.replayable,
        passed=result.passed,
        outcome=result.outcome,
        error=result.error,
        verdicts=[
            {
                "assertion": v.assertion.describe(),
                "kind": v.assertion.kind,
                "passed": v.passed,
                "detail": v.detail,
            }
            for v in result.verdicts
        ],
        wrong=[v.assertion.describe() for v in result.wrong],
        figures=found,
        wall_s=result.wall_s,
        sim_s=found["sim_s"] or 0.0,
        core_s=sum(s["cpu"]["cpu_s"] for s in stations.values() if isinstance(s.get("cpu"), dict)),
        node=node,
        kept=kept,
    )


@dataclass(frozen=True)
class PlanFile:
    """`plan.json`: the whole campaign's plan, and the slice this directory runs."""

    campaign: str
    path: str  # the campaign file's
    version: str
    shard: str  # "K/N", or "" for the whole plan
    all_runs: tuple[RunSpec, ...]  # the whole campaign's, in plan order
    min_rates: dict[str, float]  # scenario name -> its min pass rate
    time: str
    keep: str

    @property
    def runs(self) -> list[RunSpec]:
        """The runs this directory is to run: its shard of the plan, or all of it."""
        if not self.shard:
            return list(self.all_runs)
        k, _, n = self.shard.partition("/")
        return shard(list(self.all_runs), int(k), int(n))

    def min_rate(self, scenario_name: str) -> float:
        return self.min_rates.get(scenario_name, 1.0)


class Store:
    """A campaign directory's files; records are added by the driver only."""

    def __init__(self, directory: Path) -> None:
        self.dir = directory
        self._lock = threading.Lock()

    def run_dir(self, run_id: str) -> Path:
        return self.dir / RUNS_DIR / run_id

    def write_plan(
        self, campaign: Campaign, runs: list[RunSpec], version: str, shard_k_n: tuple[int, int] | None = None
    ) -> PlanFile:
        """Write `plan.json` for the whole plan `runs` of `campaign`, this directory running the
        shard `shard_k_n` of it (None: all)."""
        self.dir.mkdir(parents=True, exist_ok=True)
        planned = PlanFile(
            campaign=campaign.name,
            path=str(campaign.path.resolve()),
            version=version,
            shard=f"{shard_k_n[0]}/{shard_k_n[1]}" if shard_k_n else "",
            all_runs=tuple(runs),
            min_rates={s.name: campaign.min_rate(s.name) for s in campaign.scenarios},
            time=campaign.time,
            keep=campaign.keep,
        )
        self.write_plan_file(planned)
        return planned

    def write_plan_file(self, planned: PlanFile) -> None:
        data = {
            **{f.name: getattr(planned, f.name) for f in dataclasses.fields(planned) if f.name != "all_runs"},
            "runs": [r.to_json() for r in planned.all_runs],
        }
        self.dir.mkdir(parents=True, exist_ok=True)
        partial = self.dir / f".{PLAN_FILE}.partial"
        partial.write_text(json.dumps(data, indent=1) + "\n")
        os.replace(partial, self.dir / PLAN_FILE)

    def read_plan(self) -> PlanFile:
        path = self.dir / PLAN_FILE
        try:
            data = json.loads(path.read_text())
            runs = tuple(RunSpec.from_json(r) for r in data.pop("runs"))
            return PlanFile(**data, all_runs=runs)
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise ConfigError(
                "plan", f"no campaign plan here ({exc!r}): is it a campaign directory?", str(path)
            ) from None

    def check_plan(self, runs: list[RunSpec], version: str, shard_k_n: tuple[int, int] | None) -> PlanFile:
        """For `--resume`: the plan written here, which must be the same as `runs` (the whole
        plan), on the same abyss version and the same shard."""
        planned = self.read_plan()
        asked = f"{shard_k_n[0]}/{shard_k_n[1]}" if shard_k_n else ""
        where = str(self.dir / PLAN_FILE)
        if planned.version != version:
            raise ConfigError(
                "--resume", f"abyss changed: planned with {planned.version}, this is {version}", where
            )
        if [r.run_id for r in planned.all_runs] != [r.run_id for r in runs]:
            raise ConfigError(
                "--resume", "the campaign changed since it was planned: start a new directory", where
            )
        if planned.shard != asked:
            raise ConfigError(
                "--resume", f"planned as shard {planned.shard or 'all'}, asked {asked or 'all'}", where
            )
        return planned

    def add(self, record: RunRecord) -> None:
        """Append `record`, flushed and synced to disk before this returns."""
        line = json.dumps(record.to_json(), sort_keys=True) + "\n"
        path = self.dir / RESULTS_FILE
        with self._lock:
            self.dir.mkdir(parents=True, exist_ok=True)
            with path.open("a+b") as f:
                f.seek(0, os.SEEK_END)
                if f.tell() > 0:
                    f.seek(-1, os.SEEK_END)
                    if f.read(1) != b"\n":  # a line torn by a killed driver: end it
                        f.write(b"\n")
                f.write(line.encode())
                f.flush()
                os.fsync(f.fileno())

    def _read(self) -> tuple[dict[str, RunRecord], int]:
        records: dict[str, RunRecord] = {}
        duplicates = 0
        try:
            lines = (self.dir / RESULTS_FILE).read_bytes().split(b"\n")
        except FileNotFoundError:
            return records, 0
        for number, line in enumerate(lines, 1):
            if not line.strip():
                continue
            try:
                record = RunRecord.from_json(json.loads(line))
            except (ValueError, KeyError, TypeError):
                log.warning(
                    "%s line %d: not a whole record (torn by a killed driver?), ignored", RESULTS_FILE, number
                )
                continue
            if record.run_id in records:
                duplicates += 1
            else:
                records[record.run_id] = record
        return records, duplicates

    def records(self) -> dict[str, RunRecord]:
        """Every run's record by id, in the order they arrived; the first of a run's records wins."""
        return self._read()[0]

    def duplicates(self) -> int:
        """How many records repeat a run already recorded (and were ignored)."""
        return self._read()[1]

    def add_wall(self, wall_s: float) -> None:
        """The wall time [s] of one session (one `campaign run`, or a resumed one) that ran here."""
        with self._lock, (self.dir / SESSIONS_FILE).open("a") as f:
            f.write(json.dumps({"wall_s": wall_s}) + "\n")
            f.flush()
            os.fsync(f.fileno())

    def wall_s(self) -> float:
        """The sessions' wall time [s] summed."""
        try:
            lines = (self.dir / SESSIONS_FILE).read_text().splitlines()
        except FileNotFoundError:
            return 0.0
        total = 0.0
        for line in lines:
            try:
                total += float(json.loads(line)["wall_s"])
            except (ValueError, KeyError, TypeError):
                continue
        return total
