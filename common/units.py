"""Parse values written with their units: `20mbit`, `150ms`, `5%`, `1500B`."""

from __future__ import annotations

import math
import re
from collections.abc import Mapping

from abyss.common.errors import ConfigError

_NUMBER = r"\s*([0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)\s*"
_RATE = {"bit": 1.0, "kbit": 1e3, "mbit": 1e6, "gbit": 1e9, "bps": 8.0, "kbps": 8e3, "mbps": 8e6, "gbps": 8e9}
_TIME = {"s": 1.0, "ms": 1e-3, "us": 1e-6}
_SIZE = {"b": 1, "kb": 1024, "mb": 1024**2}


def _parse(field: str, text: str | float | int, units: Mapping[str, float], kind: str, example: str) -> float:
    if isinstance(text, (int, float)) and not isinstance(text, bool):
        raise ConfigError(
            field, f"{text!r} has no unit; write it like {example!r} (units: {', '.join(units)})"
        )
    m = re.fullmatch(_NUMBER + r"([A-Za-z%]*)\s*", str(text))
    if not m or m.group(2).lower() not in units:
        raise ConfigError(field, f"{text!r} is not a {kind} like {example!r} (units: {', '.join(units)})")
    return float(m.group(1)) * units[m.group(2).lower()]


def parse_rate_bps(field: str, text: str | float) -> float:
    """`20mbit` -> 2e7 [bit/s]; `unlimited` -> inf. Units as tc writes them: bit, kbit, mbit,
    gbit (bits) and bps, kbps, mbps, gbps (bytes)."""
    if str(text).strip().lower() in ("unlimited", "inf"):
        return math.inf
    value = _parse(field, text, _RATE, "rate", "20mbit")
    if value <= 0:
        raise ConfigError(field, f"{text!r}: a rate must be positive (or 'unlimited')")
    return value


def parse_time_s(field: str, text: str | float) -> float:
    """`150ms` -> 0.15 [s]."""
    return _parse(field, text, _TIME, "duration", "150ms")


def parse_fraction(field: str, text: str | float) -> float:
    """`5%` -> 0.05; must lie in [0, 100] %."""
    value = _parse(field, text, {"%": 0.01}, "percentage", "5%")
    if not 0.0 <= value <= 1.0:
        raise ConfigError(field, f"{text!r}: a percentage must lie in [0%, 100%]")
    return value


def parse_size_bytes(field: str, text: str | float) -> int:
    """`1500B` -> 1500 [bytes]."""
    return int(_parse(field, text, _SIZE, "size", "1500B"))


def format_rate(rate_bps: float) -> str:
    if math.isinf(rate_bps):
        return "unlimited"
    for unit, scale in (("gbit", 1e9), ("mbit", 1e6), ("kbit", 1e3)):
        if rate_bps >= scale:
            return f"{rate_bps / scale:g}{unit}"
    return f"{rate_bps:g}bit"


def format_time(seconds: float) -> str:
    return f"{seconds * 1e3:g}ms"


def format_fraction(fraction: float) -> str:
    return f"{fraction * 100:g}%"
