"""A message's schema, read from its dataclass fields: the field kinds (`array`, `scalar`,
`blob`), their checks, and `Message`, the base every message class derives from (and registers
in `MESSAGES` by its name). Every check raises `BadInput` with the field and what is wrong."""

from __future__ import annotations

import dataclasses
import functools
import math
import typing
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar, NamedTuple

import numpy as np

from abyss.common.errors import BadInput

MESSAGES: dict[str, type[Message]] = {}
# an arm's joints, as messages bound them: any robot package's arm (description.robot), generously
MAX_ARM_JOINTS = 16
SMALL_ARRAY_SIZE = 64  # an array up to this size is range-checked as Python numbers (numpy's calls cost more)


def array(
    dtype: str,
    shape: tuple[int | None, ...],
    lo: float = -math.inf,
    hi: float = math.inf,
    max_rows: int = 100_000,
    default: tuple[float, ...] | None = None,
) -> Any:
    """A numpy array field: fixed dtype, shape (None: any length up to max_rows), range; with
    `default`, a field that may be left out (appended to a message, as a new version's are)."""
    meta = {"dtype": np.dtype(dtype), "shape": shape, "lo": lo, "hi": hi, "max_rows": max_rows}
    if default is None:
        return field(metadata=meta)
    return field(default_factory=functools.partial(np.array, default, meta["dtype"]), metadata=meta)


def scalar(lo: float = -math.inf, hi: float = math.inf, choices: tuple[str, ...] = ()) -> Any:
    return field(metadata={"lo": lo, "hi": hi, "choices": choices})


def blob(max_bytes: int) -> Any:
    """A bytes field of at most `max_bytes`."""
    return field(metadata={"max_bytes": max_bytes})


def _check_number(name: str, kind: type[int] | type[float], lo: float, hi: float, value: Any) -> Any:
    if kind is float and isinstance(value, int) and not isinstance(value, bool):
        value = float(value)
    if not isinstance(value, kind) or isinstance(value, bool):
        raise BadInput(f"{name}: expected {kind.__name__}, got {type(value).__name__}")
    if kind is float and not math.isfinite(value):
        raise BadInput(f"{name}: not finite ({value})")
    if not lo <= value <= hi:
        raise BadInput(f"{name}: {value} outside [{lo}, {hi}]")
    return value


def _plainly_within(value: np.ndarray, lo: float, hi: float) -> bool:
    """True if a small array's values are all finite and in [lo, hi], told without numpy's calls; False
    for a large array or one in doubt (a NaN, an infinity, a sum that overflows), which the full checks
    then judge."""
    if value.size > SMALL_ARRAY_SIZE:
        return False
    values = (value if value.ndim == 1 else value.ravel()).tolist()
    return not values or (math.isfinite(sum(values)) and lo <= min(values) and max(values) <= hi)


def _check_array(name: str, meta: Mapping[str, Any], value: Any) -> np.ndarray:
    if not isinstance(value, np.ndarray):
        value = np.asarray(value, dtype=meta["dtype"])
    if value.dtype != meta["dtype"]:
        raise BadInput(f"{name}: dtype {value.dtype}, expected {meta['dtype']}")
    shape = meta["shape"]
    if value.shape != shape and (
        value.ndim != len(shape)
        or any(want is not None and got != want for got, want in zip(value.shape, shape, strict=True))
    ):
        raise BadInput(f"{name}: shape {value.shape}, expected {shape} (None: any)")
    if value.ndim and value.shape[0] > meta["max_rows"]:
        raise BadInput(f"{name}: {value.shape[0]} rows, at most {meta['max_rows']}")
    if not _plainly_within(value, meta["lo"], meta["hi"]):
        if value.dtype.kind == "f" and not np.all(np.isfinite(value)):
            raise BadInput(f"{name}: contains NaN or infinity")
        if value.size and (value.min() < meta["lo"] or value.max() > meta["hi"]):
            raise BadInput(f"{name}: values outside [{meta['lo']}, {meta['hi']}]")
    return _frozen(value)


def _frozen(value: np.ndarray) -> np.ndarray:
    """`value` itself if it is a view of bytes (as decoded: no one can change it), else a read-only copy."""
    base = value.base
    while isinstance(base, np.ndarray):
        base = base.base
    if isinstance(base, bytes):
        return value
    value = np.array(value, copy=True)
    value.flags.writeable = False
    return value


Check = Callable[[Any], Any]  # a field's value -> the value checked (an array: read-only); raises BadInput


def _checker(name: str, kind: Any, meta: Mapping[str, Any]) -> Check:
    """The check of field `name` of type `kind`, chosen once per message class."""
    if kind is np.ndarray:
        return functools.partial(_check_array, name, meta)
    if kind in (float, int):
        lo, hi = meta.get("lo", -math.inf), meta.get("hi", math.inf)
        return functools.partial(_check_number, name, kind, lo, hi)
    return functools.partial(_check_field, name, kind, meta)


def _check_field(name: str, kind: Any, meta: Mapping[str, Any], value: Any) -> Any:
    if kind is bytes:
        if not isinstance(value, bytes) or len(value) > meta.get("max_bytes", 16 * 2**20):
            raise BadInput(f"{name}: expected at most {meta.get('max_bytes', 16 * 2**20)} bytes")
        return value
    if kind is bool:
        if not isinstance(value, bool):
            raise BadInput(f"{name}: expected bool, got {type(value).__name__}")
        return value
    if kind is str:
        if not isinstance(value, str) or len(value) > 4096:
            raise BadInput(f"{name}: expected a string of at most 4096 characters")
        if meta.get("choices") and value not in meta["choices"]:
            raise BadInput(f"{name}: {value!r} not one of {meta['choices']}")
        return value
    if typing.get_origin(kind) is tuple:  # tuple[str, ...]
        if not isinstance(value, (list, tuple)) or len(value) > 256:
            raise BadInput(f"{name}: expected a list of at most 256 strings")
        return tuple(_check_field(f"{name}[{i}]", str, {}, v) for i, v in enumerate(value))
    if typing.get_origin(kind) is dict:
        value_kind = typing.get_args(kind)[1]
        if not isinstance(value, dict) or len(value) > 256:
            raise BadInput(f"{name}: expected a map of at most 256 entries")
        return {
            _check_field(f"{name} key", str, {}, k): _checker(f"{name}[{k}]", value_kind, {})(v)
            for k, v in value.items()
        }
    raise TypeError(f"{name}: unsupported field type {kind}")


class Schema(NamedTuple):
    """What checking and coding a message class needs, read from its dataclass fields once."""

    checks: tuple[tuple[str, Check], ...]  # each field's name and check, in order
    names: frozenset[str]
    arrays: dict[str, dict[str, Any]]  # the array fields' metadata, with how they travel (`_wire`)


def _wire(meta: Mapping[str, Any]) -> dict[str, Any]:
    """An array field's metadata, with its dtype as it travels (little-endian) and that dtype's name."""
    wire_dtype = meta["dtype"].newbyteorder("<")
    return {**meta, "wire_dtype": wire_dtype, "wire_str": wire_dtype.str}


def _read_schema(cls: type) -> Schema:
    hints = typing.get_type_hints(cls)
    fields = dataclasses.fields(cls)
    return Schema(
        tuple((f.name, _checker(f.name, hints[f.name], dict(f.metadata))) for f in fields),
        frozenset(f.name for f in fields),
        {f.name: _wire(f.metadata) for f in fields if hints[f.name] is np.ndarray},
    )


# Per message class, cached. Typed as taking any class: mypy holds a frozen dataclass's class
# object unhashable (it reads the instances' __hash__), so functools.cache's Hashable arguments
# would refuse type[Message].
schema_of: Callable[[type], Schema] = functools.cache(_read_schema)


@dataclass(frozen=True)
class Message:
    """Base of every message: a frozen dataclass validated on construction."""

    TYPE: ClassVar[str] = ""
    VERSION: ClassVar[int] = 1
    COMPRESSED: ClassVar[bool] = False  # sent as one zstd frame

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        cls.TYPE = cls.__name__
        MESSAGES[cls.TYPE] = cls

    def __post_init__(self) -> None:
        for name, check in schema_of(type(self)).checks:
            object.__setattr__(self, name, check(getattr(self, name)))


def check_unit_quaternion(quat_wxyz: np.ndarray) -> None:
    norm = math.hypot(*quat_wxyz.tolist())
    if abs(norm - 1.0) > 1e-3:
        raise BadInput(f"orientation_wxyz_world: not a unit quaternion (norm {norm:.4f})")
