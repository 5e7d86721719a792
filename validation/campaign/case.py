"""One case of a campaign: one scenario in one variant, over its seeds, and what its runs say (its
pass rate, how often each assertion came out wrong, its failing runs, its figures'
distributions), for the report (report.py) and its plots (figures.py)."""

from __future__ import annotations

import statistics
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

from abyss.validation.campaign.stats import flaky, wilson
from abyss.validation.campaign.store import RunRecord

RUN_ERROR = "(the run did not complete)"  # an assertion-failure key: runs that ended in an error


@dataclass(frozen=True)
class Case:
    """One scenario in one variant, over its seeds."""

    scenario: str
    variant: str
    values: dict[str, Any]
    planned: int
    min_rate: float
    records: tuple[RunRecord, ...]  # by seed
    why_not_replayable: dict[str, str] = field(default_factory=dict)  # run id -> why, from the plan

    @property
    def runs(self) -> int:
        return len(self.records)

    @property
    def passes(self) -> int:
        return sum(r.passed for r in self.records)

    @property
    def rate(self) -> float | None:
        return self.passes / self.runs if self.runs else None

    @property
    def ok(self) -> bool:
        """At or above its min pass rate, with at least one result."""
        return self.runs > 0 and self.passes >= self.min_rate * self.runs - 1e-9

    def failures(self) -> dict[str, int]:
        """How many runs each assertion came out wrong in (RUN_ERROR: runs that did not complete)."""
        counts = Counter(a for r in self.records for a in dict.fromkeys(r.wrong))
        counts.update(RUN_ERROR for r in self.records if r.error)
        return dict(sorted(counts.items(), key=lambda kv: (-kv[1], kv[0])))

    def failing(self) -> list[dict[str, Any]]:
        return [
            {
                "run_id": r.run_id,
                "seed": r.seed,
                "outcome": r.outcome,
                "why": (r.error.splitlines() or [""])[0] if r.error else "; ".join(r.wrong),
                "replayable": r.replayable,
                "why_not_replayable": self.why_not_replayable.get(r.run_id, ""),
            }
            for r in self.records
            if not r.passed
        ]

    def figures(self) -> dict[str, dict[str, float | int]]:
        """Each figure's count, median, min and max over the case's runs that have it."""
        names = list(dict.fromkeys(name for r in self.records for name in r.figures))
        stats = {}
        for name in names:
            values = [v for r in self.records if (v := r.figures.get(name)) is not None]
            if values:
                stats[name] = {
                    "n": len(values),
                    "median": statistics.median(values),
                    "min": min(values),
                    "max": max(values),
                }
        return stats

    def data(self) -> dict[str, Any]:
        low, high = wilson(self.passes, self.runs)
        return {
            "scenario": self.scenario,
            "variant": self.variant,
            "values": self.values,
            "planned": self.planned,
            "runs": self.runs,
            "pending": self.planned - self.runs,
            "passes": self.passes,
            "pass_rate": self.rate,
            "wilson_95": [low, high],
            "flaky": flaky(self.passes, self.runs),
            "min_pass_rate": self.min_rate,
            "ok": self.ok,
            "assertion_failures": self.failures(),
            "failing_runs": self.failing(),
            "figures": self.figures(),
        }
