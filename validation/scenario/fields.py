"""A scenario's tables read through the one typed reader (common.reading), with what a type hint
adds for a scenario: `Annotated[str, OneOf(...)]` names a field's allowed values (checked once
read), and a required field's error names them too. Also the configuration's partial tables:
`section.field` keys nested, merged, and typed as a Config reads them."""

from __future__ import annotations

import dataclasses
import typing
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Annotated, Any, Protocol, TypeVar

from abyss.common.config import Config, load
from abyss.common.errors import ConfigError
from abyss.common.reading import read_table

T = TypeVar("T")


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
    """The dataclass `cls` from `table` (common.reading.read_table), then each field given
    checked against the rules of its `Annotated` hint; errors name `where`.field."""
    hints = typing.get_type_hints(cls, include_extras=True)
    try:
        value = read_table(cls, table, where)
    except ConfigError as exc:
        allowed = allowed_of(hints.get(exc.field.rpartition(".")[2]))
        if exc.reason == "is required" and allowed:
            raise ConfigError(exc.field, f"is required: one of {', '.join(allowed)}") from None
        raise
    for name in table:
        _check(f"{where}.{name}", hints[name], getattr(value, name))
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


def nested(table: dict[str, Any]) -> dict[str, Any]:
    """A configuration table with `section.field` keys (a TOML quoted key, a campaign's matrix
    key) as nested tables, merged with the tables written nested."""
    out: dict[str, Any] = {}
    for key, value in table.items():
        *sections, leaf = key.split(".")
        node = out
        for section in sections:
            node = node.setdefault(section, {})
            if not isinstance(node, dict):
                raise ConfigError(key, f"{section} is a field, not a section")
        node[leaf] = merge(node.get(leaf, {}), nested(value)) if isinstance(value, dict) else value
    return out


def merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    """`over` on top of `base`, table by table (neither changed)."""
    out = dict(base)
    for key, value in over.items():
        both = isinstance(value, dict) and isinstance(out.get(key), dict)
        out[key] = merge(out[key], value) if both else value
    return out


def configured(partial: dict[str, Any], where: str = "") -> dict[str, Any]:
    """The partial configuration `partial` (nested or `section.field` keys) checked as a Config
    reads it, its values as read (a list as a list, a number as a number); errors name
    `where`.field."""
    table = nested(partial)
    try:
        config = load(None, base=table)
    except ConfigError as exc:
        raise ConfigError(f"{where}.{exc.field}" if where else exc.field, exc.reason) from None
    return _typed(table, config)


def configuration(partial: dict[str, Any]) -> Config:
    """The whole configuration: the defaults with `partial` on top."""
    return load(None, base=nested(partial))


def _typed(table: dict[str, Any], section: Any) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for name, value in table.items():
        read = getattr(section, name)
        out[name] = _typed(value, read) if dataclasses.is_dataclass(read) else _plain(read)
    return out


def _plain(value: Any) -> Any:
    """A read value as JSON and TOML write it: tuples as lists."""
    return [_plain(v) for v in value] if isinstance(value, tuple | list) else value
