"""The wire form of a message and back. A message on the wire is a msgpack map: `type` (name),
`version` (schema version), `seq` (per-key sequence number), `stamp_s` (sender's wall clock [s])
and `body` (the fields). numpy arrays travel as `{dtype, shape, data}` with raw little-endian
bytes. A class with `COMPRESSED` (the scene stream, whose bytes go over the satellite) sends that
map as one zstd frame (content size and checksum in its header); `decode` takes either form, a
frame announcing more than `MAX_DECOMPRESSED_BYTES` refused before anything is allocated.
`decode()` checks the type, the version, every field's type, dtype, shape, range and finiteness,
and raises `BadMessage` with the reason; nothing malformed gets further, and nothing but
`BadInput` (and msgpack's and zstd's own errors, at their calls) is caught as malformed: a defect
of abyss's own surfaces as the bug it is."""

from __future__ import annotations

import math
import threading
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Generic, TypeVar, overload

import msgpack
import numpy as np
import zstandard

from abyss.common.errors import BadInput, BadMessage
from abyss.interface.messages.schema import MESSAGES, Message, schema_of

ZSTD_MAGIC = b"\x28\xb5\x2f\xfd"  # a frame's first bytes; an envelope's first is a msgpack map's (0x85)
ZSTD_LEVEL = 19  # the satellite's bytes are dearer than the vessel's milliseconds (a 16 kB update: ~10 ms)
MAX_DECOMPRESSED_BYTES = 64 * 2**20
_zstd = threading.local()  # a compressor and a decompressor per thread: zstd's contexts are not shared
# What every compressed message repeats, given to zstd as a raw-content dictionary: the envelope's
# and the scene update's names and OctoMap's binary header (an update of a few hundred bytes would
# otherwise carry some 250 bytes of them). A constant, not built from a live tree: both ends must
# hold the same bytes whatever their OctoMap.
ZSTD_DICTIONARY = msgpack.packb(
    [
        "type",
        "version",
        "seq",
        "stamp_s",
        "body",
        "SceneUpdate",
        "kind",
        "snapshot",
        "delta",
        "scene_seq",
        "resolution_m",
        "octree",
        "colors",
        "dtype",
        "|u1",
        "shape",
        "data",
        "sim_time_s",
        "stream_id",
    ]
) + (
    b"# Octomap OcTree binary file\n# (feel free to add / change comments, but leave the first line as "
    b"it is!)\n#\nid OcTree\nsize \nres 0.1\ndata\n"
)


def _pack(value: Any, array: Mapping[str, Any] | None) -> Any:
    """A field's value as it travels; an array (`array`: its field's metadata) as its map, little-endian."""
    if array is None:
        return value
    wire_dtype = array["wire_dtype"]
    little = value if value.dtype == wire_dtype else value.astype(wire_dtype)
    return {"dtype": array["wire_str"], "shape": list(value.shape), "data": little.tobytes()}


def encode(message: Message, seq: int, stamp_s: float) -> bytes:
    schema = schema_of(type(message))
    body = {name: _pack(getattr(message, name), schema.arrays.get(name)) for name, _ in schema.checks}
    packed = msgpack.packb(
        {"type": message.TYPE, "version": message.VERSION, "seq": seq, "stamp_s": stamp_s, "body": body},
        use_bin_type=True,
    )
    if not message.COMPRESSED:
        return packed
    if not hasattr(_zstd, "compressor"):
        _zstd.compressor = zstandard.ZstdCompressor(
            level=ZSTD_LEVEL, write_checksum=True, dict_data=_dictionary()
        )
    return _zstd.compressor.compress(packed)


def wire_bytes(message: Message) -> int:
    """What `message` takes on the wire, compressed where its class is (envelope included, give or
    take the few bytes its sequence number and stamp take)."""
    return len(encode(message, 0, 0.0))


def _dictionary() -> zstandard.ZstdCompressionDict:
    return zstandard.ZstdCompressionDict(ZSTD_DICTIONARY, dict_type=zstandard.DICT_TYPE_RAWCONTENT)


def unwrap(data: bytes) -> bytes:
    """An encoded message's msgpack map: `data` itself, or the zstd frame's content. BadInput
    on a frame that does not decompress, or announces more than MAX_DECOMPRESSED_BYTES."""
    if not data.startswith(ZSTD_MAGIC):
        return data
    try:
        size = zstandard.frame_content_size(data)
    except zstandard.ZstdError as exc:
        raise BadInput(f"not a zstd frame: {exc}") from None
    if not 0 <= size <= MAX_DECOMPRESSED_BYTES:
        raise BadInput(f"a zstd frame of {size} bytes (at most {MAX_DECOMPRESSED_BYTES}; -1: unsaid)")
    if not hasattr(_zstd, "decompressor"):
        _zstd.decompressor = zstandard.ZstdDecompressor(dict_data=_dictionary())
    try:
        return _zstd.decompressor.decompress(data)
    except zstandard.ZstdError as exc:
        raise BadInput(f"a zstd frame that does not decompress: {exc}") from None


M = TypeVar("M", bound=Message)


@dataclass(frozen=True)
class Received(Generic[M]):
    """A decoded message with its envelope; `Received[Telemetry]` from a key that carries Telemetry."""

    key: str
    message: M
    seq: int
    stamp_s: float


ENVELOPE_KEYS = frozenset(("type", "version", "seq", "stamp_s", "body"))
ARRAY_MAP_KEYS = frozenset(("dtype", "shape", "data"))
# what msgpack raises on bytes that are not msgpack (or not the msgpack it will take: a map key that
# is not a string, nesting too deep, an ext type it cannot read); caught at its call, and only there
MSGPACK_ERRORS = (msgpack.UnpackException, ValueError, TypeError)


def _unpack_array(name: str, raw: Any, meta: Mapping[str, Any]) -> np.ndarray:
    """An array field's map as a read-only array over its bytes, which the field's check then checks."""
    if not isinstance(raw, dict) or raw.keys() != ARRAY_MAP_KEYS:
        raise BadInput(f"{name}: expected an array map with dtype, shape and data")
    dtype = meta["wire_dtype"]
    if raw["dtype"] != meta["wire_str"]:
        raise BadInput(f"{name}: dtype {raw['dtype']!r}, expected {meta['wire_str']!r}")
    shape, data = raw["shape"], raw["data"]
    if (
        not isinstance(shape, list)
        or len(shape) != len(meta["shape"])
        or not all(isinstance(n, int) and not isinstance(n, bool) and n >= 0 for n in shape)
    ):
        raise BadInput(f"{name}: bad shape {shape!r}, expected {len(meta['shape'])} dimensions")
    if not isinstance(data, bytes):
        raise BadInput(f"{name}: data of {type(data).__name__}, expected bytes")
    if len(data) != dtype.itemsize * math.prod(shape):
        raise BadInput(f"{name}: {len(data)} data bytes do not fill shape {shape}")
    value = np.ndarray(shape, dtype, data)
    return value if dtype == meta["dtype"] else value.astype(meta["dtype"])


@overload
def decode(key: str, data: bytes, expected: type[M]) -> Received[M]: ...
@overload
def decode(key: str, data: bytes, expected: None = None) -> Received[Message]: ...
def decode(key: str, data: bytes, expected: type[Message] | None = None) -> Received[Any]:
    """Decode and validate; raises BadMessage(key, reason) on anything malformed. `expected`: the
    message class the key carries (another is malformed too); None for whatever comes (a
    recording's or an observer's reader, which looks at the type it gets)."""
    try:
        envelope = msgpack.unpackb(unwrap(data), raw=False, strict_map_key=True)
    except BadInput as exc:
        raise BadMessage(key, exc.reason) from None
    except MSGPACK_ERRORS as exc:
        raise BadMessage(key, f"not msgpack: {exc}") from None
    if not isinstance(envelope, dict) or envelope.keys() != ENVELOPE_KEYS:
        raise BadMessage(key, "not a message envelope (type, version, seq, stamp_s, body)")
    name = envelope["type"]
    cls = MESSAGES.get(name) if isinstance(name, str) else None
    if cls is None:
        raise BadMessage(key, f"unknown message type {name!r}")
    if expected is not None and cls is not expected:
        raise BadMessage(key, f"message type {name}, expected {expected.TYPE}")
    if envelope["version"] != cls.VERSION:
        raise BadMessage(key, f"{name} schema version {envelope['version']!r}, expected {cls.VERSION}")
    seq, stamp_s, body = envelope["seq"], envelope["stamp_s"], envelope["body"]
    if not isinstance(seq, int) or isinstance(seq, bool) or seq < 0:
        raise BadMessage(key, f"bad sequence number {seq!r}")
    if not isinstance(stamp_s, float) or not math.isfinite(stamp_s):
        raise BadMessage(key, f"bad stamp {stamp_s!r}")
    schema = schema_of(cls)
    if not isinstance(body, dict) or body.keys() != schema.names:
        fields = sorted(map(str, body)) if isinstance(body, dict) else body
        raise BadMessage(key, f"{name} fields {fields!r}, expected {sorted(schema.names)}")
    try:
        arrays = schema.arrays
        message = cls(**{n: _unpack_array(n, v, arrays[n]) if n in arrays else v for n, v in body.items()})
    except BadInput as exc:
        raise BadMessage(key, f"{name}: {exc.reason}") from None
    return Received(key, message, seq, stamp_s)
