"""A campaign file (TOML): which scenarios (paths or globs relative to the file), how many seeds,
a matrix of variations over hop profiles, configuration fields and event parameters, the time
source, the pass rates each scenario must reach and which runs to keep. A bad file is refused at
load with the file, the field and what is allowed."""

from __future__ import annotations

import dataclasses
import glob
import json
import os
import re
import tomllib
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

from abyss.common.errors import ConfigError
from abyss.common.reading import OneOf, read
from abyss.config.linkprofile import load_profiles
from abyss.description.models import shipped_names
from abyss.interface import keys
from abyss.validation.scenario.events import EVENTS, action_of, fields_of
from abyss.validation.scenario.fields import configured
from abyss.validation.scenario.spec import Scenario, load_scenario, scenario_of

TIMES = ("lockstep", "sim", "real")  # the time source a campaign asks for
KEEPS = ("failing", "all", "none")  # which runs' directories are kept whole
REQUIRED = {  # what a required field takes, said when it is missing
    "scenarios": "a list of scenario files or globs, relative to this file",
    "seeds": "a count of at least 1 (5: seeds 0 to 4) or a non-empty list of distinct whole numbers >= 0",
}
RESERVED = {  # configuration fields the campaign sets itself: matrix key -> the campaign's field
    "seed": "seeds",
    "system": "name (each run gets a system id of its own)",
    "time.mode": "time",
}
EVENT_KEY = re.compile(r"^events\[(\d+)\]\.(\w+)$")
# matrix keys that stand for a configuration field: the robot and site packages (a shipped one's
# name, or a directory relative to the campaign file)
PACKAGE_KEYS = {"robot": "simulation.robot", "site": "simulation.site"}


@dataclass(frozen=True)
class Campaign:
    name: str
    path: Path
    description: str
    scenarios: tuple[Scenario, ...]
    seeds: tuple[int, ...]
    matrix: tuple[tuple[str, tuple[Any, ...]], ...]  # key -> its values, in the file's order
    time: str  # lockstep | sim | real
    min_pass_rate: float  # [0, 1], every scenario's unless min_pass_rate_of names it
    min_pass_rate_of: dict[str, float]
    keep: str  # failing | all | none

    def min_rate(self, scenario_name: str) -> float:
        """The pass rate [0, 1] the scenario must reach in each variant."""
        return self.min_pass_rate_of.get(scenario_name, self.min_pass_rate)


def event_fields() -> tuple[str, ...]:
    """Every field an event kind takes (scenario.events.EVENTS), each once, the common first."""
    return tuple(dict.fromkeys(f for kind in EVENTS.values() for f in fields_of(kind)))


def apply_value(table: dict[str, Any], key: str, value: Any) -> None:
    """One matrix value into a scenario's table (as its TOML file reads): `links.<hop>` its
    profile, `events[i].<field>` that event's field, anything else a configuration field, the
    value as typed (the scenario's [config] reads `section.field` keys)."""
    if key.startswith("links."):
        table.setdefault("links", {})[key.removeprefix("links.")] = value
    elif key in PACKAGE_KEYS:
        table.setdefault("config", {})[PACKAGE_KEYS[key]] = value
    elif m := EVENT_KEY.match(key):
        table["events"][int(m[1])][m[2]] = value
    else:
        table.setdefault("config", {})[key] = value


def scenario_with(
    text: str, path: Path, values: Iterable[tuple[str, Any]], seed: int | None = None
) -> Scenario:
    """The scenario of file `path` (its `text`) with the matrix `values` applied and, if given,
    the configuration's `seed`."""
    try:
        table = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError("scenario", f"cannot read: {exc}", str(path)) from None
    for key, value in values:
        apply_value(table, key, value)
    if seed is not None:
        table.setdefault("config", {})["seed"] = seed
    return scenario_of(table, str(path))


def load_campaign(path: Path) -> Campaign:
    """The campaign file at `path`, every scenario it names loaded and every matrix key checked."""
    try:
        table = tomllib.loads(path.read_text())
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise ConfigError("campaign", f"cannot read: {exc}", str(path)) from None
    try:
        return _campaign(table, path)
    except ConfigError as exc:
        if exc.source:  # a scenario file's own error: its file and field
            raise
        raise ConfigError(exc.field, exc.reason, str(path)) from None


@dataclass(frozen=True)
class CampaignFile:
    """A campaign file's fields as written, read by the one typed reader (common.reading)."""

    name: str
    scenarios: list[str] | str  # paths or globs, relative to the file
    seeds: int | list[int]  # a count (5: seeds 0 to 4) or the seeds themselves
    description: str = ""
    exclude: list[str] | str = dataclasses.field(default_factory=list)
    time: Annotated[str, OneOf(TIMES)] = "lockstep"
    min_pass_rate: float = 1.0
    min_pass_rate_of: dict[str, float] = dataclasses.field(default_factory=dict)
    keep: Annotated[str, OneOf(KEEPS)] = "failing"
    matrix: dict[str, Any] | None = None


def _campaign(table: dict[str, Any], path: Path) -> Campaign:
    try:
        fields = read(CampaignFile, table, "")
    except ConfigError as exc:
        if exc.field in ("scenarios", "seeds") and exc.reason == "is required":
            raise ConfigError(exc.field, f"is required: {REQUIRED[exc.field]}") from None
        raise
    try:
        keys.check_system_id(fields.name)
    except ConfigError as exc:
        raise ConfigError("name", exc.reason) from None
    scenarios = _scenarios(
        path.parent, _paths(fields.scenarios, "scenarios"), _paths(fields.exclude, "exclude")
    )
    return Campaign(
        name=fields.name,
        path=path,
        description=fields.description,
        scenarios=scenarios,
        seeds=_seeds(fields.seeds),
        matrix=_matrix(fields.matrix, scenarios, path.parent),
        time=fields.time,
        min_pass_rate=_rate(fields.min_pass_rate, "min_pass_rate"),
        min_pass_rate_of=_rates_of(fields.min_pass_rate_of, scenarios),
        keep=fields.keep,
    )


def _paths(value: list[str] | str, name: str) -> list[str]:
    paths = [value] if isinstance(value, str) else value
    if name == "scenarios" and not paths:
        raise ConfigError(name, "needs at least one path or glob")
    return paths


def _matched(folder: Path, patterns: list[str], field: str) -> list[Path]:
    """The files each of `patterns` names, relative to `folder` (the campaign file's), once each,
    in the patterns' order and each pattern's matches sorted."""
    found: list[Path] = []
    for i, pattern in enumerate(patterns):
        full = pattern if os.path.isabs(pattern) else os.path.join(glob.escape(str(folder)), pattern)
        matches = sorted(Path(p).resolve() for p in glob.glob(full, recursive=True) if Path(p).is_file())
        if not matches:
            raise ConfigError(f"{field}[{i}]", f"{pattern!r} matches no file (relative to {folder})")
        found += [m for m in matches if m not in found]
    return found


def _scenarios(folder: Path, patterns: list[str], excluded: list[str]) -> tuple[Scenario, ...]:
    out = set(_matched(folder, excluded, "exclude"))
    paths = [p for p in _matched(folder, patterns, "scenarios") if p not in out]
    if not paths:
        raise ConfigError("scenarios", "every file matched is excluded: nothing to run")
    scenarios = tuple(load_scenario(p) for p in paths)
    seen: dict[str, Path] = {}
    for s in scenarios:
        if s.name in seen:
            raise ConfigError(
                "scenarios", f"two files name the scenario {s.name!r}: {seen[s.name]}, {s.path}"
            )
        seen[s.name] = s.path
    return scenarios


def _seeds(value: int | list[int]) -> tuple[int, ...]:
    if isinstance(value, int) and value >= 1:
        return tuple(range(value))
    if isinstance(value, list) and value and all(v >= 0 for v in value) and len(set(value)) == len(value):
        return tuple(value)
    raise ConfigError("seeds", f"{value!r}: expected {REQUIRED['seeds']}")


def _rate(value: float, field: str) -> float:
    if not 0.0 <= value <= 1.0:
        raise ConfigError(field, f"{value:g}: a pass rate from 0 to 1")
    return value


def _rates_of(table: dict[str, Any], scenarios: tuple[Scenario, ...]) -> dict[str, float]:
    names = [s.name for s in scenarios]
    rates = {}
    for name in table:
        if name not in names:
            raise ConfigError(
                f"min_pass_rate_of.{name}", f"names no scenario of the campaign: {', '.join(names)}"
            )
        rates[name] = _rate(table[name], f"min_pass_rate_of.{name}")
    return rates


def _matrix(
    table: Any, scenarios: tuple[Scenario, ...], base: Path
) -> tuple[tuple[str, tuple[Any, ...]], ...]:
    if table is None:
        return ()
    if not isinstance(table, dict) or not table:
        raise ConfigError(
            "matrix", "a table of keys, each with a list of values; leave it out for no variations"
        )
    matrix = []
    for key, values in table.items():
        where = f"matrix.{key}"
        if not isinstance(values, list) or not values:
            raise ConfigError(where, f"{values!r}: expected a list of at least one value")
        if not all(_plain(v) for v in values):
            raise ConfigError(where, f"{values!r}: values are strings, numbers, booleans or lists of them")
        if len({json.dumps(v) for v in values}) != len(values):
            raise ConfigError(where, f"{values!r}: a value twice")
        field_name = key
        if key in PACKAGE_KEYS:  # a directory is the campaign file's, wherever the runs run
            field_name, shipped = PACKAGE_KEYS[key], shipped_names(key)
            values = [v if v in shipped else str((base / str(v)).resolve()) for v in values]
        _check_key(field_name, values, scenarios, where)
        matrix.append((key, tuple(values)))
    return tuple(matrix)


def _plain(value: Any) -> bool:
    if isinstance(value, list):
        return all(_plain(v) for v in value)
    return isinstance(value, str | int | float | bool)


def _check_key(key: str, values: list[Any], scenarios: tuple[Scenario, ...], where: str) -> None:
    """Refuse a matrix key that names no hop, event field or configuration field, or a value
    that one does not take."""
    kinds = (
        f"a matrix key is links.<hop> ({', '.join(keys.HOPS)}), events[i].<field> "
        f"({', '.join(event_fields())}) or a configuration field (section.field, as --set takes)"
    )
    if key in RESERVED:
        raise ConfigError(where, f"set by the campaign's {RESERVED[key]}, not the matrix")
    if key.startswith("links."):
        hop = key.removeprefix("links.")
        if hop not in keys.HOPS:
            raise ConfigError(where, f"no hop {hop!r}; {kinds}")
        profiles = sorted(load_profiles())
        for value in values:
            if value not in profiles:
                raise ConfigError(where, f"{value!r} is no link profile; profiles: {', '.join(profiles)}")
    elif m := EVENT_KEY.match(key):
        _check_event(int(m[1]), m[2], key, values, scenarios, where)
    elif key.startswith("events"):
        raise ConfigError(where, kinds)
    else:
        for value in values:
            try:
                configured({key: value})
            except ConfigError as exc:
                raise ConfigError(where, f"{value!r}: {exc.field}: {exc.reason}; {kinds}") from None


def _check_event(
    index: int, field: str, key: str, values: list[Any], scenarios: tuple[Scenario, ...], where: str
) -> None:
    """Every scenario has the event, its action takes the field, and each value is one it takes."""
    if field not in event_fields():
        raise ConfigError(where, f"no event field {field!r}; fields: {', '.join(event_fields())}")
    for s in scenarios:
        if index >= len(s.events):
            raise ConfigError(
                where, f"scenario {s.name} ({s.path}) has no events[{index}]: {len(s.events)} events"
            )
        action = action_of(s.events[index])
        takes = fields_of(EVENTS[action])
        if field not in takes:
            raise ConfigError(
                where,
                f"scenario {s.name}'s events[{index}] is a {action} event: it takes no {field}, only "
                f"{', '.join(takes)}",
            )
        text = s.path.read_text()
        for value in values:
            try:
                scenario_with(text, s.path, [(key, value)])
            except ConfigError as exc:
                raise ConfigError(
                    where, f"{value!r} in scenario {s.name}: {exc.field}: {exc.reason}"
                ) from None
