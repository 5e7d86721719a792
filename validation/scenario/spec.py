"""A validation scenario, read from TOML: which stations run (and which are the user's own),
each hop's profile, configuration overrides, timed events (link changes, faults, a station
killed) and the assertions that make the verdict. A bad file fails at load with the file, the
field and what is allowed."""

from __future__ import annotations

import dataclasses
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, assert_never, get_args

from abyss.common import keys
from abyss.common.config import load
from abyss.common.config.system import TimeConfig
from abyss.common.errors import BadInput, ConfigError
from abyss.common.linkprofile import load_profiles
from abyss.common.messages import FAULTS, INTERVENTION_PHASES, PERCEPTION_SOURCES
from abyss.common.models import panel

USES = ("distributed", "interface", "degradation", "parallel", "fault-recovery")
Action = Literal["link", "fault", "kill"]  # what an event does
ACTIONS: tuple[Action, ...] = get_args(Action)
# assertion kind -> the fields it takes (beyond `kind`), each with its type
ASSERTIONS: dict[str, dict[str, type]] = {
    "mission_done": {"within_s": float},
    "final_error": {"vehicle_m": float, "ee_m": float, "ee_deg": float},
    "failsafe": {
        "from_s": float,
        "to_s": float,
        "enter_within_s": float,
        "leave_within_s": float,
        "phase": str,
    },
    "commands_answered": {},
    "scene": {"min_occupied_cells": float, "objects": list},
    "link": {"hop": str, "direction": str, "stat": str, "max": float, "min": float},
    "stations": {"max_restarts": float, "max_drift_m": float},
    "deadlines": {"min_met": float, "station": str, "loop": str},
    "shed": {"station": str, "min": float, "max": float},
    "intervention": {"part": str, "outcome": str, "reason": str},
    "arm_limits": {"margin_deg": float},
    "perception": {
        "source": str,
        "min_points_per_s": float,
        "max_points_per_s": float,
        "min_mapped_s": float,
    },
    "recognition": {"min_confidence": float, "max_confidence": float},
}
OUTCOMES = ("done", "failed")  # of an intervention


@dataclass(frozen=True)
class Event:
    at_s: float  # after all stations are up [s], or after onboard first reports `phase`
    action: Action
    phase: str = ""  # an intervention's phase (messages.INTERVENTION_PHASES), e.g. turn
    hop: str = ""
    profile: str = ""
    fault: str = ""
    target: str = ""
    value: float = 0.0
    station: str = ""

    def when(self) -> str:
        return f"{self.at_s:g} s into {self.phase}" if self.phase else f"t={self.at_s:g} s"

    def describe(self) -> str:
        match self.action:
            case "link":
                return f"link {self.hop} -> {self.profile}"
            case "fault":
                return f"fault {self.fault} {self.target} {self.value:g}".rstrip()
            case "kill":
                return f"kill {self.station}"
            case _:
                assert_never(self.action)


@dataclass(frozen=True)
class Assertion:
    kind: str
    args: dict[str, Any]

    def describe(self) -> str:
        return self.kind + "".join(f" {k}={v}" for k, v in self.args.items())


@dataclass(frozen=True)
class Scenario:
    name: str
    path: Path
    description: str
    use: str
    duration_s: float
    stop_when_done: bool
    external: tuple[str, ...]
    restart: bool
    links: dict[str, str]
    config: tuple[str, ...]  # section.field=value, as --set
    events: tuple[Event, ...]
    assertions: tuple[Assertion, ...]
    expect_failed: tuple[str, ...] = field(default=())  # assertion kinds that must fail

    @property
    def time(self) -> TimeConfig:
        """The run's time source, from its configuration (`time.mode`, `time.speed`)."""
        return load(None, list(self.config)).time

    @property
    def holds_s(self) -> tuple[float, ...]:
        """In lockstep, the simulated times its events land on (the simulation holds there while
        the runner carries them out: common.lockstep); none on another time source."""
        return tuple(sorted({e.at_s for e in self.events})) if self.time.mode == "lockstep" else ()

    def on_time(self, mode: str, speed: str | None) -> tuple[Scenario, str]:
        """This scenario on the time source `abyss scenario run --time` asks for, and why not where
        it cannot follow it (an external station, a real component, runs on the wall clock)."""
        if mode != "real" and self.external:
            return self, f"runs in real time: external {', '.join(self.external)} keeps the wall clock"
        if mode != "real" and any(c.startswith("cpu.") for c in self.config):
            return self, "runs in real time: a CPU cap is a share of wall time"
        if mode == "lockstep" and any(e.phase for e in self.events):
            return (
                self,
                "runs in real time: an event timed on an intervention's phase lands when shore sees it",
            )
        items = [f"time.mode={mode}", *([f"time.speed={speed}"] if speed is not None else [])]
        if mode == "real":
            items.append("time.speed=1")
        kept = tuple(c for c in self.config if not c.startswith(("time.mode=", "time.speed=")))
        return dataclasses.replace(self, config=(*kept, *items)), ""


def _take(table: dict[str, Any], name: str, kind: type, where: str, default: Any = None) -> Any:
    if name not in table:
        if default is None:
            raise ConfigError(f"{where}.{name}", "is required")
        return default
    value = table.pop(name)
    if kind is float and isinstance(value, int) and not isinstance(value, bool):
        value = float(value)
    if not isinstance(value, kind) or (isinstance(value, bool) and kind is not bool):
        raise ConfigError(f"{where}.{name}", f"expected {kind.__name__}, got {value!r}")
    return value


def _no_more(table: dict[str, Any], where: str, allowed: list[str]) -> None:
    if table:
        raise ConfigError(f"{where}.{sorted(table)[0]}", f"unknown field; allowed: {', '.join(allowed)}")


def _choice(value: str, allowed: tuple[str, ...] | list[str], where: str) -> str:
    if value not in allowed:
        raise ConfigError(where, f"{value!r} not one of {', '.join(allowed)}")
    return value


def _action(value: str, where: str) -> Action:
    for action in ACTIONS:
        if value == action:
            return action
    raise ConfigError(where, f"{value!r} not one of {', '.join(ACTIONS)}")


def _event(table: dict[str, Any], where: str) -> Event:
    table = dict(table)
    at_s = _take(table, "at_s", float, where)
    action = _action(_take(table, "action", str, where), f"{where}.action")
    phase = _take(table, "phase", str, where, "")
    if phase:
        _choice(phase, INTERVENTION_PHASES[1:], f"{where}.phase")
    if action == "link":
        hop = keys.check_hop(_take(table, "hop", str, where))
        name = _take(table, "profile", str, where)
        _choice(name, list(load_profiles()), f"{where}.profile")
        event = Event(at_s, action, phase, hop=hop, profile=name)
    elif action == "fault":
        fault = _choice(_take(table, "fault", str, where), FAULTS, f"{where}.fault")
        event = Event(
            at_s,
            action,
            phase,
            fault=fault,
            target=_take(table, "target", str, where, ""),
            value=_take(table, "value", float, where, 0.0),
        )
    else:
        event = Event(at_s, action, phase, station=keys.check_station(_take(table, "station", str, where)))
    _no_more(table, where, [f for f in Event.__dataclass_fields__ if f != "action"])
    return event


def _assertion(table: dict[str, Any], where: str) -> Assertion:
    table = dict(table)
    kind = _choice(_take(table, "kind", str, where), list(ASSERTIONS), f"{where}.kind")
    fields = ASSERTIONS[kind]
    args = {name: _take(table, name, fields[name], where) for name in list(table) if name in fields}
    if args.get("phase"):
        _choice(args["phase"], INTERVENTION_PHASES[1:], f"{where}.phase")
    if "outcome" in args:
        _choice(args["outcome"], OUTCOMES, f"{where}.outcome")
    if "station" in args:
        _choice(args["station"], keys.STATIONS, f"{where}.station")
    if kind == "perception":
        if "source" not in args:
            raise ConfigError(f"{where}.source", f"is required: one of {', '.join(PERCEPTION_SOURCES)}")
        _choice(args["source"], PERCEPTION_SOURCES, f"{where}.source")
    if kind == "intervention":
        if "part" not in args:
            raise ConfigError(f"{where}.part", "is required")
        try:
            panel.part_kind(args["part"])
        except BadInput as exc:
            raise ConfigError(f"{where}.part", str(exc)) from None
    _no_more(table, where, list(fields))
    return Assertion(kind, args)


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


def _scenario(table: dict[str, Any], path: Path) -> Scenario:
    name = _take(table, "name", str, "scenario")
    keys.check_system_id(name)
    links = _take(table, "links", dict, "scenario", {})
    for hop, profile in links.items():
        keys.check_hop(hop)
        _choice(profile, list(load_profiles()), f"links.{hop}")
    overrides = tuple(f"{k}={v}" for k, v in _take(table, "config", dict, "scenario", {}).items())
    load(None, [*overrides, *(f"links.{hop}={p}" for hop, p in links.items())])  # fails here if bad
    scenario = Scenario(
        name=name,
        path=path,
        description=_take(table, "description", str, "scenario", ""),
        use=_choice(_take(table, "use", str, "scenario"), USES, "use"),
        duration_s=_take(table, "duration_s", float, "scenario"),
        stop_when_done=_take(table, "stop_when_done", bool, "scenario", True),
        external=tuple(keys.check_station(s) for s in _take(table, "external", list, "scenario", [])),
        restart=_take(table, "restart", bool, "scenario", False),
        links=links,
        config=overrides,
        events=tuple(
            _event(e, f"events[{i}]") for i, e in enumerate(_take(table, "events", list, "scenario", []))
        ),
        assertions=tuple(
            _assertion(a, f"assert[{i}]") for i, a in enumerate(_take(table, "assert", list, "scenario"))
        ),
        expect_failed=tuple(_take(table, "expect_failed", list, "scenario", [])),
    )
    _no_more(
        table,
        "scenario",
        [
            "name",
            "description",
            "use",
            "duration_s",
            "stop_when_done",
            "external",
            "restart",
            "links",
            "config",
            "events",
            "assert",
            "expect_failed",
        ],
    )
    for kind in scenario.expect_failed:
        _choice(kind, [a.kind for a in scenario.assertions], "expect_failed")
    if not scenario.assertions:
        raise ConfigError("assert", "a scenario needs at least one assertion")
    return scenario
