"""A validation scenario, read from TOML: which stations run (and which are the user's own),
each hop's profile, the configuration (a partial table on the defaults), timed events (one kind
per file in `events/`) and the assertions that make the verdict (checks.CHECKS). Every table
is read through the one typed reader (common.reading): a bad file fails at load with the file,
the field and what is allowed."""

from __future__ import annotations

import dataclasses
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal, get_args

from abyss.common.errors import ConfigError
from abyss.common.reading import OneOf, read
from abyss.config import Config
from abyss.config.system import TimeConfig
from abyss.interface import keys
from abyss.validation.scenario.checks import CHECKS, OUTCOMES, Assertion, fields_of
from abyss.validation.scenario.events import EVENTS, Event
from abyss.validation.scenario.fields import configuration, configured, merge

Use = Literal["distributed", "interface", "degradation", "parallel", "fault-recovery"]
USES: tuple[Use, ...] = get_args(Use)

__all__ = ["OUTCOMES", "USES", "Assertion", "Event", "Scenario", "load_scenario", "scenario_of"]


@dataclass(frozen=True)
class Scenario:
    name: str
    path: Path
    description: str
    use: Use
    duration_s: float
    stop_when_done: bool
    external: tuple[str, ...]
    restart: bool
    links: dict[str, str]  # hop -> profile
    config: dict[str, Any]  # a partial configuration (nested tables), its values typed
    events: tuple[Event, ...]
    assertions: tuple[Assertion, ...]
    expect_failed: tuple[str, ...] = field(default=())  # assertion kinds that must fail

    @property
    def configuration(self) -> Config:
        """The run's whole configuration: the defaults, its `config`, its `links` on top."""
        return configuration(self.up_table(holds=False))

    @property
    def time(self) -> TimeConfig:
        """The run's time source, from its configuration (`time.mode`, `time.speed`)."""
        return configuration(self.config).time

    @property
    def held(self) -> bool:
        """In lockstep with events: each lands on its period, the simulation held there while the
        runner carries it out (timing.lockstep)."""
        return self.time.mode == "lockstep" and bool(self.events)

    @property
    def holds_s(self) -> tuple[float, ...]:
        """In lockstep, the simulated times its events not timed on a phase land on; none on
        another time source."""
        return tuple(sorted({e.at_s for e in self.events if not e.phase})) if self.held else ()

    @property
    def phase_held(self) -> bool:
        """In lockstep, events timed on an intervention's phase: their holds are added as onboard
        reports the phase (`time.phase_holds`)."""
        return self.held and any(e.phase for e in self.events)

    def up_table(self, holds: bool = True) -> dict[str, Any]:
        """The configuration `abyss up --config` is given: `config`, `links` on top and, in
        lockstep, the holds (`time.holds_s`, `time.phase_holds`)."""
        table = merge(self.config, {"links": self.links} if self.links else {})
        if holds and self.holds_s:
            table = merge(table, {"time": {"holds_s": list(self.holds_s)}})
        if holds and self.phase_held:
            table = merge(table, {"time": {"phase_holds": True}})
        return table

    def on_time(self, mode: str, speed: str | None) -> tuple[Scenario, str]:
        """This scenario on the time source `abyss scenario run --time` asks for, and why not where
        it cannot follow it (an external station, a real component, runs on the wall clock)."""
        if mode != "real" and self.external:
            return self, f"runs in real time: external {', '.join(self.external)} keeps the wall clock"
        if mode != "real" and self.config.get("cpu"):
            return self, "runs in real time: a CPU cap is a share of wall time"
        kept = {k: v for k, v in self.config.get("time", {}).items() if k not in ("mode", "speed")}
        time = {**kept, "mode": mode, **({"speed": speed} if speed is not None else {})}
        if mode == "real":
            time["speed"] = "1"
        return dataclasses.replace(self, config=configured({**self.config, "time": time})), ""


@dataclass(frozen=True)
class ScenarioFile:
    """A scenario file's top-level fields (`assert_` is its `assert`, a Python keyword)."""

    name: str
    use: Use
    duration_s: float
    assert_: tuple[dict[str, Any], ...]
    description: str = ""
    stop_when_done: bool = True
    external: tuple[Annotated[str, OneOf(keys.STATIONS)], ...] = ()
    restart: bool = False
    links: dict[str, str] = field(default_factory=dict)
    config: dict[str, Any] = field(default_factory=dict)
    events: tuple[dict[str, Any], ...] = ()
    expect_failed: tuple[str, ...] = ()


def _kind(table: Any, key: str, registry: dict[str, Any], where: str) -> tuple[Any, dict[str, Any]]:
    """The registered kind a table's `key` names, and the table's other fields."""
    if not isinstance(table, dict):
        raise ConfigError(where, f"expected a table, got {table!r}")
    if key not in table:
        raise ConfigError(f"{where}.{key}", f"is required: one of {', '.join(registry)}")
    name = table[key]
    if name not in registry:
        raise ConfigError(f"{where}.{key}", f"{name!r} not one of {', '.join(registry)}")
    return registry[name], {k: v for k, v in table.items() if k != key}


def _event(table: Any, where: str) -> Event:
    kind, rest = _kind(table, "action", EVENTS, where)
    try:
        return read(kind, rest, where)
    except ConfigError as exc:
        if "unknown field" not in exc.reason:
            raise
        raise ConfigError(exc.field, f"{exc.reason} (a {table['action']} event)") from None


def _assertion(table: Any, where: str) -> Assertion:
    check, rest = _kind(table, "kind", CHECKS, where)
    fields: object = read(fields_of(check), rest, where)
    return Assertion(table["kind"], {name: getattr(fields, name) for name in rest})


def load_scenario(path: Path) -> Scenario:
    try:
        table = tomllib.loads(path.read_text())
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise ConfigError("scenario", f"cannot read: {exc}", str(path)) from None
    try:
        return _scenario(table, path)
    except ConfigError as exc:
        raise ConfigError(exc.field, exc.reason, str(path)) from None


def scenario_of(table: dict[str, Any], where: str = "<table>") -> Scenario:
    """A scenario from a table shaped as the TOML file (for tests that build their own)."""
    try:
        return _scenario(dict(table), Path(where))
    except ConfigError as exc:
        raise ConfigError(exc.field, exc.reason, where) from None


def _read_file(table: dict[str, Any]) -> ScenarioFile:
    renamed = {("assert_" if k == "assert" else k): v for k, v in table.items()}
    try:
        return read(ScenarioFile, renamed, "scenario")
    except ConfigError as exc:
        raise ConfigError(
            exc.field.replace("assert_", "assert"), exc.reason.replace("assert_", "assert")
        ) from None


def _scenario(table: dict[str, Any], path: Path) -> Scenario:
    top = _read_file(table)
    try:
        keys.check_system_id(top.name)
    except ConfigError as exc:
        raise ConfigError("scenario.name", exc.reason) from None
    config = configured(top.config, "config")
    links = configured({"links": top.links})["links"] if top.links else {}
    scenario = Scenario(
        name=top.name,
        path=path,
        description=top.description,
        use=top.use,
        duration_s=top.duration_s,
        stop_when_done=top.stop_when_done,
        external=top.external,
        restart=top.restart,
        links=links,
        config=config,
        events=tuple(_event(e, f"events[{i}]") for i, e in enumerate(top.events)),
        assertions=tuple(_assertion(a, f"assert[{i}]") for i, a in enumerate(top.assert_)),
        expect_failed=top.expect_failed,
    )
    scenario.configuration  # noqa: B018  (the whole, its config and links together, fails here if bad)
    for i, kind in enumerate(scenario.expect_failed):
        kinds = [a.kind for a in scenario.assertions]
        if kind not in kinds:
            raise ConfigError(
                f"expect_failed[{i}]", f"{kind!r} not one of the scenario's assertions: {', '.join(kinds)}"
            )
    if not scenario.assertions:
        raise ConfigError("assert", "a scenario needs at least one assertion")
    return scenario
