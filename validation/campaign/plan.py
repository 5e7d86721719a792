"""A campaign's plan: every scenario times every variant (the product of the matrix's lists)
times every seed, in a stable order, each run ready to travel to a Ray worker on another host
(it carries its scenario, not a path to read) and named by a hash of what makes it."""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from abyss.common.errors import ConfigError
from abyss.validation.campaign.spec import Campaign, scenario_with
from abyss.validation.campaign.version import abyss_version
from abyss.validation.scenario.spec import Scenario


def value_text(value: Any) -> str:
    """A matrix value as a variant's name shows it: floats with `:g`, lists as JSON."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return f"{value:g}"
    if isinstance(value, list):
        return json.dumps(value)
    return str(value)


@dataclass(frozen=True)
class Variant:
    values: tuple[tuple[str, Any], ...]  # (matrix key, value), in the matrix's order

    @property
    def name(self) -> str:
        """`default` for no matrix, else `key=value key=value`."""
        return " ".join(f"{k}={value_text(v)}" for k, v in self.values) or "default"

    def as_dict(self) -> dict[str, Any]:
        return dict(self.values)


def variants(campaign: Campaign) -> list[Variant]:
    """The product of the matrix's lists, in order (the last key varies fastest)."""
    keys = [key for key, _ in campaign.matrix]
    return [
        Variant(tuple(zip(keys, combo, strict=True)))
        for combo in itertools.product(*(v for _, v in campaign.matrix))
    ]


def run_id(text: str, variant: Variant, seed: int, time: str, version: str) -> str:
    """16 hex digits of the SHA-256 of the canonical JSON of what makes a run: the scenario
    file's text, the variant's values, the seed, the time source asked for and abyss's version."""
    canonical = json.dumps(
        [text, [list(kv) for kv in variant.values], seed, time, version],
        sort_keys=True,
        separators=(",", ":"),
        ensure_ascii=False,
    )
    return hashlib.sha256(canonical.encode()).hexdigest()[:16]


@dataclass(frozen=True)
class RunSpec:
    run_id: str
    scenario: Scenario  # the variant, the seed and the time source applied: ready for run_scenario
    scenario_name: str
    variant: Variant
    seed: int
    time: str  # the time source the run really has
    replayable: bool  # True iff it runs in lockstep: its failures replay bit for bit
    why_not_replayable: str
    text: str = ""  # the scenario file's text, to rebuild the scenario without the file
    time_asked: str = ""  # the campaign's time source

    def to_json(self) -> dict[str, Any]:
        return {
            "run_id": self.run_id,
            "scenario_name": self.scenario_name,
            "scenario_path": str(self.scenario.path),  # for people: the scenario is its text
            "scenario_text": self.text,
            "variant": [list(kv) for kv in self.variant.values],
            "seed": self.seed,
            "time_asked": self.time_asked,
            "time": self.time,
            "replayable": self.replayable,
            "why_not_replayable": self.why_not_replayable,
        }

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> RunSpec:
        """The run `to_json` wrote, its scenario rebuilt from the text (no file read); its id as
        written (the version it was planned with is not this process's)."""
        variant = Variant(tuple((str(k), v) for k, v in data["variant"]))
        spec = spec_of(
            data["scenario_text"], Path(data["scenario_path"]), variant, data["seed"], data["time_asked"], ""
        )
        if spec.scenario_name != data["scenario_name"]:
            raise ConfigError(
                "scenario_name", f"{data['scenario_name']!r} but the text names {spec.scenario_name!r}"
            )
        return dataclasses.replace(spec, run_id=data["run_id"])


def spec_of(text: str, path: Path, variant: Variant, seed: int, time: str, version: str) -> RunSpec:
    """One run: the scenario file's `text` (from `path`) with `variant` and `seed` applied, on the
    time source `time` where the scenario can follow it."""
    scenario = scenario_with(text, path, variant.values, seed)
    scenario, why = scenario.on_time(time, None)
    really = scenario.time.mode
    if really != "lockstep" and not why:
        why = f"runs in {really} time: its failures replay only statistically"
    return RunSpec(
        run_id=run_id(text, variant, seed, time, version),
        scenario=scenario,
        scenario_name=scenario.name,
        variant=variant,
        seed=seed,
        time=really,
        replayable=really == "lockstep",
        why_not_replayable="" if really == "lockstep" else why,
        text=text,
        time_asked=time,
    )


def plan(campaign: Campaign) -> list[RunSpec]:
    """Every run of the campaign: by scenario (the campaign's order), variant (the matrix
    product's order), seed."""
    version = abyss_version()
    runs = []
    for scenario in campaign.scenarios:
        text = scenario.path.read_text()
        for variant in variants(campaign):
            runs += [
                spec_of(text, scenario.path, variant, seed, campaign.time, version) for seed in campaign.seeds
            ]
    return runs


def parse_shard(text: str) -> tuple[int, int]:
    """`K/N` -> (K, N), 1 <= K <= N."""
    k, sep, n = text.partition("/")
    if sep and k.strip().isdigit() and n.strip().isdigit() and 1 <= int(k) <= int(n):
        return int(k), int(n)
    raise ConfigError("--shard", f"{text!r}: K/N with 1 <= K <= N")


def shard(runs: list[RunSpec], k: int, n: int) -> list[RunSpec]:
    """The K-th of N slices (1-based) by position in the plan: every N-th run from the K-th."""
    if not 1 <= k <= n:
        raise ConfigError("--shard", f"{k}/{n}: K/N with 1 <= K <= N")
    return runs[k - 1 :: n]
