"""The one typed reader: a value checked against its type hint, a table read into a frozen
dataclass, and what an `Annotated` hint adds (`OneOf`: the values a string field takes, checked
once read and named when the field is missing). The configuration, scenarios, their events and
assertions, campaigns and link profiles all read through it, so that every error says the same
thing the same way: the field (dotted, with list indices), and what is allowed. Strings from the
command line (`--set`) are converted; TOML and JSON values are taken as they are typed."""

from __future__ import annotations

import dataclasses
import json
import math
import types
import typing
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Annotated, Any, Protocol, TypeVar

from abyss.common.errors import ConfigError

T = TypeVar("T")


def read_value(name: str, kind: Any, value: Any) -> Any:
    """`value` checked against the type hint `kind` (a dataclass, Literal, tuple, list, dict,
    union with None, float, int, bool or str), CLI strings converted; `name` is the field's
    dotted name for the error."""
    origin = typing.get_origin(kind)
    if typing.get_origin(kind) is Annotated:
        return read_value(name, typing.get_args(kind)[0], value)
    if dataclasses.is_dataclass(kind):
        return read_table(kind, value, name)
    if origin is typing.Literal:
        allowed = typing.get_args(kind)
        read = read_value(name, type(allowed[0]), value)
        if read not in allowed:
            raise ConfigError(name, f"{read!r} not one of {', '.join(map(str, allowed))}")
        return read
    if origin in (typing.Union, types.UnionType):
        options = [a for a in typing.get_args(kind) if a is not type(None)]
        if value is None and len(options) < len(typing.get_args(kind)):
            return None
        errors = []
        for option in options:  # the first that reads it
            try:
                return read_value(name, option, value)
            except ConfigError as exc:
                errors.append(exc.reason)
        raise ConfigError(name, " or ".join(errors))
    if origin in (tuple, list):
        return _sequence(name, kind, value)
    if origin is dict:
        key_kind, value_kind = typing.get_args(kind)
        if not isinstance(value, dict):
            raise ConfigError(name, f"expected a table, got {value!r}")
        return {
            read_value(name, key_kind, k): read_value(f"{name}.{k}", value_kind, v) for k, v in value.items()
        }
    if kind is typing.Any:
        return value
    return _scalar(name, kind, value)


def _sequence(name: str, kind: Any, value: Any) -> Any:
    args = typing.get_args(kind)
    if isinstance(value, str):
        try:
            value = json.loads(value)
        except json.JSONDecodeError as exc:
            raise ConfigError(name, f"expected a list, got {value!r} ({exc.msg})") from None
    if not isinstance(value, (list, tuple)):
        raise ConfigError(name, f"expected a list, got {value!r}")
    if typing.get_origin(kind) is list or (len(args) == 2 and args[1] is Ellipsis):
        items = [read_value(f"{name}[{i}]", args[0] if args else Any, v) for i, v in enumerate(value)]
        return items if typing.get_origin(kind) is list else tuple(items)
    if len(value) != len(args):
        raise ConfigError(name, f"expected {len(args)} values, got {len(value)}")
    return tuple(read_value(f"{name}[{i}]", a, v) for i, (a, v) in enumerate(zip(args, value, strict=True)))


def _scalar(name: str, kind: Any, value: Any) -> Any:
    if kind is float:
        try:
            number = float(value) if not isinstance(value, bool) else math.nan
        except (TypeError, ValueError):
            number = math.nan
        if not math.isfinite(number):
            raise ConfigError(name, f"expected a finite number, got {value!r}")
        return number
    if kind is int:
        if isinstance(value, str) and value.strip().lstrip("-").isdigit():
            value = int(value)
        if not isinstance(value, int) or isinstance(value, bool):
            raise ConfigError(name, f"expected a whole number, got {value!r}")
        return value
    if kind is bool:
        if isinstance(value, str) and value.lower() in ("true", "false"):
            value = value.lower() == "true"
        if not isinstance(value, bool):
            raise ConfigError(name, f"expected true or false, got {value!r}")
        return value
    if kind is str:
        if not isinstance(value, str):
            raise ConfigError(name, f"expected a string, got {value!r}")
        return value
    raise ConfigError(name, f"unsupported type {kind}")


def read_table(cls: Any, table: Any, prefix: str = "") -> Any:
    """The frozen dataclass `cls` from a table: an unknown field is refused first (so that a
    typo reads as what it is, with the allowed names), then a required one missing, then each
    value against its hint; the dataclass's own `__post_init__` checks the rest."""
    if not isinstance(table, dict):
        raise ConfigError(prefix or "config", f"expected a table, got {table!r}")

    def dotted(n: str) -> str:
        return f"{prefix}.{n}" if prefix else n

    hints = typing.get_type_hints(cls)
    fields = [f for f in dataclasses.fields(cls) if f.init]
    allowed = {f.name for f in fields}
    unknown = set(table) - allowed
    if unknown:
        raise ConfigError(dotted(sorted(unknown)[0]), f"unknown field; allowed: {', '.join(sorted(allowed))}")
    for f in fields:
        required = f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
        if required and f.name not in table:
            raise ConfigError(dotted(f.name), "is required")
    values = {n: read_value(dotted(n), hints[n], v) for n, v in table.items()}
    return cls(**values)


class Rule(Protocol):
    """What a field's `Annotated` hint asks of its value beyond its type."""

    def check(self, name: str, value: Any) -> None: ...


@dataclass(frozen=True)
class OneOf:
    """The values a string field takes (a callable: looked up when read); `blank`: "" too."""

    allowed: Iterable[str] | Callable[[], Iterable[str]]
    blank: bool = False

    def values(self) -> tuple[str, ...]:
        return tuple(self.allowed() if callable(self.allowed) else self.allowed)

    def check(self, name: str, value: Any) -> None:
        if not (self.blank and value == "") and value not in self.values():
            raise ConfigError(name, f"{value!r} not one of {', '.join(self.values())}")


def read(cls: type[T], table: Any, where: str) -> T:
    """The dataclass `cls` from `table` (read_table), then each field given checked against the
    rules of its `Annotated` hint; errors name `where`.field."""
    hints = typing.get_type_hints(cls, include_extras=True)
    try:
        value = read_table(cls, table, where)
    except ConfigError as exc:
        allowed = allowed_of(hints.get(exc.field.rpartition(".")[2]))
        if exc.reason == "is required" and allowed:
            raise ConfigError(exc.field, f"is required: one of {', '.join(allowed)}") from None
        raise
    for name in table:
        _check(f"{where}.{name}" if where else name, hints[name], getattr(value, name))
    return value


def allowed_of(hint: Any) -> tuple[str, ...]:
    """The values a `Literal` or `Annotated[..., OneOf]` hint allows; () for another."""
    if typing.get_origin(hint) is typing.Literal:
        return tuple(map(str, typing.get_args(hint)))
    if typing.get_origin(hint) is Annotated:
        return next((r.values() for r in hint.__metadata__ if isinstance(r, OneOf)), ())
    return ()


def _check(name: str, hint: Any, value: Any) -> None:
    if typing.get_origin(hint) is Annotated:
        for rule in hint.__metadata__:
            rule.check(name, value)
    elif typing.get_origin(hint) in (tuple, list):
        for i, item in enumerate(value):
            _check(f"{name}[{i}]", typing.get_args(hint)[0], item)
