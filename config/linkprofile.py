"""Link profiles: what a hop does to traffic, named in `profiles.toml`.

Delay and jitter are read as netem reads `delay 100ms 10ms distribution normal`:
`delay` is the mean one-way delay and `jitter` the standard deviation of the chosen
distribution (for `uniform`, the half-width). The paper's "100 ms mean delay with 10 ms
variance" is therefore `delay = "100ms"`, `jitter = "10ms"`.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import tomllib
import types
import typing
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from abyss.common.errors import ConfigError, UnknownProfile
from abyss.common.reading import read_table
from abyss.common.units import (
    format_fraction,
    format_rate,
    format_time,
    parse_fraction,
    parse_rate_bps,
    parse_size_bytes,
    parse_time_s,
)
from abyss.config.fields import one_of

PROFILES_FILE = Path(__file__).with_name("profiles.toml")
TRACES_DIR = Path(__file__).with_name("traces")  # the shipped delivery traces, NAME.trace
Distribution = Literal["normal", "uniform", "pareto", "paretonormal"]
DISTRIBUTIONS: tuple[Distribution, ...] = typing.get_args(Distribution)
LossModel = Literal["bernoulli", "gilbert-elliott"]
LOSS_MODELS: tuple[LossModel, ...] = typing.get_args(LossModel)
Transport = Literal["tcp", "udp"]
TRANSPORTS: tuple[Transport, ...] = typing.get_args(Transport)
OutageTimes = Literal["exponential", "fixed"]
OUTAGE_TIMES: tuple[OutageTimes, ...] = typing.get_args(OutageTimes)


@functools.cache
def load_trace(name: str) -> tuple[float, ...]:
    """A delivery trace in mahimahi's format (mm-link): one packet delivery opportunity of 1500
    bytes per line, its time in whole milliseconds, ascending; it repeats with the last line's
    time as its period. `name`: a shipped trace (config/traces/NAME.trace) or a file's path.
    Returns the times [s]; ConfigError naming the line that is wrong."""
    path = TRACES_DIR / f"{name}.trace" if "/" not in name and not name.endswith(".trace") else Path(name)
    shipped = ", ".join(sorted(p.stem for p in TRACES_DIR.glob("*.trace")))
    try:
        lines = path.read_text().split()
    except OSError as exc:
        raise ConfigError("trace", f"{name!r}: {exc.strerror or exc}; shipped: {shipped}") from None
    times_ms: list[int] = []
    for number, line in enumerate(lines, 1):
        if not line.isdigit() or (times_ms and int(line) < times_ms[-1]):
            raise ConfigError(
                "trace", f"{path} line {number}: {line!r} is not a whole number of ms, ascending"
            )
        times_ms.append(int(line))
    if not times_ms or times_ms[-1] <= 0:
        raise ConfigError("trace", f"{path}: no delivery opportunity after 0 ms")
    return tuple(t / 1000.0 for t in times_ms)


def _trace(field: str, value: Any) -> str:
    """A shipped trace's name, or a file's path made absolute here, where the user typed it (a
    station that replays it runs in a directory of its own)."""
    name = str(value)
    if "/" in name or name.endswith(".trace"):
        name = str(Path(name).resolve())
    if name:
        load_trace(name)  # refused here, at start, naming the field
    return name


def _str(value: Any) -> str:
    return str(value).lower() if isinstance(value, bool) else str(value)


@dataclass(frozen=True)
class WrittenProfile:
    """A profile's fields as written in `profiles.toml`, `abyss link set` or a config (each left
    out keeps the profile's own), read by `common.reading` against these hints. A value with a
    unit (`Any` here: a number without its unit is refused by `common.units`, with the unit to
    write) is then converted by its parser in `FIELDS`."""

    rate: Any = None  # "20mbit", "unlimited"
    delay: Any = None  # "100ms"
    jitter: Any = None  # "10ms"
    distribution: Distribution | None = None
    correlation: Any = None  # "25%"
    loss_model: LossModel | None = None
    loss: Any = None  # "5%"
    ge_p: Any = None
    ge_r: Any = None
    ge_loss_bad: Any = None
    ge_loss_good: Any = None
    corrupt: Any = None
    deliver_corrupt: bool | None = None
    duplicate: Any = None
    reorder: Any = None
    mtu: Any = None  # "1500B"
    queue_limit: int | None = None  # [packets]
    transport: Transport | None = None
    outage_up: Any = None  # "60s"
    outage_down: Any = None
    outage_times: OutageTimes | None = None
    trace: str | None = None  # a shipped trace's name or a file's path
    seed: int | None = None


def _same(field: str, value: Any) -> Any:
    return value


# profile field as written (TOML, CLI) -> (dataclass attribute, the parser of its unit or its
# path (`_same`: the type hint read it whole), formatter)
FIELDS: dict[str, tuple[str, Callable[[str, Any], Any], Callable[[Any], str]]] = {
    "rate": ("rate_bps", parse_rate_bps, format_rate),
    "delay": ("delay_s", parse_time_s, format_time),
    "jitter": ("jitter_s", parse_time_s, format_time),
    "distribution": ("distribution", _same, _str),
    "correlation": ("correlation", parse_fraction, format_fraction),
    "loss_model": ("loss_model", _same, _str),
    "loss": ("loss", parse_fraction, format_fraction),
    "ge_p": ("ge_p", parse_fraction, format_fraction),
    "ge_r": ("ge_r", parse_fraction, format_fraction),
    "ge_loss_bad": ("ge_loss_bad", parse_fraction, format_fraction),
    "ge_loss_good": ("ge_loss_good", parse_fraction, format_fraction),
    "corrupt": ("corrupt", parse_fraction, format_fraction),
    "deliver_corrupt": ("deliver_corrupt", _same, _str),
    "duplicate": ("duplicate", parse_fraction, format_fraction),
    "reorder": ("reorder", parse_fraction, format_fraction),
    "mtu": ("mtu_bytes", parse_size_bytes, lambda v: f"{v}B"),
    "queue_limit": ("queue_limit_packets", _same, _str),
    "transport": ("transport", _same, _str),
    "outage_up": ("outage_up_s", parse_time_s, format_time),
    "outage_down": ("outage_down_s", parse_time_s, format_time),
    "outage_times": ("outage_times", _same, _str),
    "trace": ("trace", _trace, _str),
    "seed": ("seed", _same, _str),
}
MAX_QUEUE_PACKETS = 1_000_000
MAX_SEED = 2**63 - 1


@dataclass(frozen=True)
class LinkProfile:
    """One direction of a hop. Units in names; see the module docstring for jitter."""

    name: str = "ideal"
    rate_bps: float = math.inf
    delay_s: float = 0.0
    jitter_s: float = 0.0
    distribution: Distribution = "normal"
    correlation: float = 0.0  # delay correlation with the previous packet [0, 1)
    loss_model: LossModel = "bernoulli"
    loss: float = 0.0  # Bernoulli loss probability per packet
    ge_p: float = 0.0  # Gilbert-Elliott: P(good -> bad) per packet
    ge_r: float = 1.0  # P(bad -> good)
    ge_loss_bad: float = 1.0  # loss probability in the bad state (netem's 1-h)
    ge_loss_good: float = 0.0  # loss probability in the good state (netem's 1-k)
    corrupt: float = 0.0  # probability that a packet has one bit flipped
    deliver_corrupt: bool = False  # hand corrupt bytes to the receiver (tests its decoder)
    duplicate: float = 0.0
    reorder: float = 0.0  # probability that a packet skips the delay and overtakes
    mtu_bytes: int = 1500
    queue_limit_packets: int = 1000
    transport: Transport = "tcp"
    seed: int = 0
    # on-off outages, as mahimahi's mm-onoff: the link is up for `outage_up_s`, then down (every
    # packet lost) for `outage_down_s`, and so on, each time drawn from an exponential of that
    # mean or `fixed`, seeded apart from the traffic; no outages while outage_down_s is 0
    outage_up_s: float = 0.0
    outage_down_s: float = 0.0
    outage_times: OutageTimes = "exponential"
    # the hop's capacity replayed from a delivery trace (load_trace), in place of `rate`; "" none
    trace: str = ""

    def __post_init__(self) -> None:
        one_of("distribution", self.distribution, DISTRIBUTIONS)
        one_of("loss_model", self.loss_model, LOSS_MODELS)
        one_of("transport", self.transport, TRANSPORTS)
        one_of("outage_times", self.outage_times, OUTAGE_TIMES)
        if self.outage_down_s > 0.0 and self.outage_up_s <= 0.0:
            raise ConfigError("outage_up", "must be above 0 s when outage_down is: how long the link is up")
        if self.mtu_bytes < 128 or self.mtu_bytes > 65535:
            raise ConfigError("mtu", f"{self.mtu_bytes}B outside [128B, 65535B]")
        if self.correlation >= 1.0:
            raise ConfigError("correlation", "must be below 100%")
        if not 1 <= self.queue_limit_packets <= MAX_QUEUE_PACKETS:
            raise ConfigError(
                "queue_limit", f"{self.queue_limit_packets} is not a whole number in [1, {MAX_QUEUE_PACKETS}]"
            )
        if not 0 <= self.seed <= MAX_SEED:
            raise ConfigError("seed", f"{self.seed} is not a whole number in [0, {MAX_SEED}]")
        for attr in ("delay_s", "jitter_s"):
            if not 0.0 <= getattr(self, attr) <= 60.0:
                raise ConfigError(attr, f"{getattr(self, attr)} s outside [0 s, 60 s]")

    @property
    def is_ideal(self) -> bool:
        """Nothing to emulate: the link can be a pass-through."""
        return (
            math.isinf(self.rate_bps)
            and self.delay_s == 0.0
            and self.jitter_s == 0.0
            and self.mean_loss == 0.0
            and self.corrupt == 0.0
            and self.duplicate == 0.0
            and self.outage_down_s == 0.0
            and not self.trace
        )

    @property
    def mean_loss(self) -> float:
        """Long-run packet loss probability."""
        if self.loss_model == "bernoulli":
            return self.loss
        if self.ge_p + self.ge_r == 0.0:
            return self.ge_loss_good
        bad = self.ge_p / (self.ge_p + self.ge_r)
        return bad * self.ge_loss_bad + (1.0 - bad) * self.ge_loss_good

    def with_fields(self, fields: Mapping[str, Any], source: str = "") -> LinkProfile:
        """A copy with fields as written in TOML or on the command line (`rate='20mbit'`): read
        through `common.reading` (an unknown field first, with the allowed ones, then each value
        against its hint), then each unit by its parser; errors name `source` and the field."""
        try:
            written = read_table(WrittenProfile, dict(fields))
            changes = {}
            for name in fields:
                attr, parse, _ = FIELDS[name]
                changes[attr] = parse(name, getattr(written, name))
            return dataclasses.replace(self, **changes)
        except ConfigError as exc:
            raise ConfigError(exc.field, exc.reason, source or exc.source) from None

    def fields(self) -> dict[str, str]:
        """Every field as written, units included; `with_fields(fields())` is the identity."""
        return {name: fmt(getattr(self, attr)) for name, (attr, _, fmt) in FIELDS.items()}


@functools.cache
def load_profiles(path: Path = PROFILES_FILE) -> Mapping[str, LinkProfile]:
    """The named profiles, read once per process (read-only)."""
    try:
        table = tomllib.loads(path.read_text())
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise ConfigError("profiles", f"cannot read: {exc}", str(path)) from None
    return types.MappingProxyType(
        {
            name: LinkProfile(name=name).with_fields(fields, source=f"{path} [{name}]")
            for name, fields in table.items()
        }
    )


def profile(name: str, overrides: Mapping[str, Any] | None = None) -> LinkProfile:
    profiles = load_profiles()
    if name not in profiles:
        raise UnknownProfile(name, sorted(profiles))
    return profiles[name].with_fields(overrides or {})
