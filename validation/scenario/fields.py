"""The configuration's partial tables as scenarios and campaigns carry them: `section.field` keys
nested, merged, and typed as a Config reads them."""

from __future__ import annotations

import dataclasses
from typing import Any

from abyss.common.errors import ConfigError
from abyss.config import Config, load, merge


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
