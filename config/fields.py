"""Checks shared by the configuration's sections and the link profiles: each raises `ConfigError`
naming the field and what is allowed."""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

from abyss.common.errors import ConfigError


def positive(name: str, value: float, allow_zero: bool = False) -> None:
    """`value` finite and above zero (or zero, with `allow_zero`), else ConfigError on `name`."""
    if not math.isfinite(value) or value < 0 or (value == 0 and not allow_zero):
        allowed = "zero or a positive number" if allow_zero else "a positive number"
        raise ConfigError(name, f"{value} must be {allowed}")


def one_of(name: str, value: Any, allowed: Iterable[Any]) -> None:
    """`value` one of `allowed` (a mode's `Literal` values, `typing.get_args`), else ConfigError on
    `name` with the allowed values."""
    allowed = tuple(allowed)
    if value not in allowed:
        shown = repr(value) if isinstance(value, str) else str(value)
        raise ConfigError(name, f"{shown} not one of {', '.join(map(str, allowed))}")
