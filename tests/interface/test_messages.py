"""The codec: round trips, and every kind of malformed input refused with its reason."""

from __future__ import annotations

import dataclasses
import math
import typing
from collections.abc import Mapping

import msgpack
import numpy as np
import pytest
import zstandard
from hypothesis import given
from hypothesis import strategies as st

from abyss.common.errors import BadInput, BadMessage
from abyss.interface.messages import (
    MESSAGES,
    ZSTD_DICTIONARY,
    ZSTD_MAGIC,
    ArmGoal,
    NavState,
    Received,
    SceneUpdate,
    Telemetry,
    VelocityRef,
    Waypoints,
    decode,
    encode,
    unwrap,
    wire_bytes,
)
from abyss.interface.messages.schema import schema_of
from abyss.validation.stress import sample_telemetry

finite = st.floats(-1e4, 1e4, allow_nan=False)


def nav(position: list[float]) -> NavState:
    return NavState(np.array(position), np.array([1.0, 0, 0, 0]), np.zeros(3), np.zeros(3), 1.5)


@given(position=st.lists(finite, min_size=3, max_size=3), seq=st.integers(0, 2**62), stamp=st.floats(0, 2e9))
def test_navstate_round_trip(position: list[float], seq: int, stamp: float) -> None:
    received = decode("k", encode(nav(position), seq, stamp))
    assert received.seq == seq and received.stamp_s == stamp
    assert isinstance(received.message, NavState)
    np.testing.assert_array_equal(received.message.position_m_world, position)
    assert not received.message.position_m_world.flags.writeable


@given(
    rows=st.lists(st.lists(finite, min_size=4, max_size=4), min_size=0, max_size=50),
    command_id=st.integers(0, 2**53),
)
def test_waypoints_round_trip(rows: list[list[float]], command_id: int) -> None:
    message = Waypoints(command_id, np.array(rows, dtype="f8").reshape(-1, 4))
    back = decode("k", encode(message, 0, 1.0)).message
    assert isinstance(back, Waypoints) and back.command_id == command_id
    np.testing.assert_array_equal(back.waypoints, message.waypoints)


@given(data=st.binary(max_size=300))
def test_random_bytes_never_crash_the_decoder(data: bytes) -> None:
    try:
        decode("k", data)
    except BadMessage as exc:
        assert exc.key == "k" and exc.reason


def _tamper(message: object, **changes: object) -> bytes:
    envelope = msgpack.unpackb(encode(message, 0, 1.0), raw=False)  # type: ignore[arg-type]
    for path, value in changes.items():
        node = envelope
        *parents, leaf = path.split("__")
        for p in parents:
            node = node[p]
        node[leaf] = value
    return msgpack.packb(envelope, use_bin_type=True)


GOOD = VelocityRef(np.zeros(3), 0.1)


@pytest.mark.parametrize(
    ("data", "reason"),
    [
        (b"\xc1", "not msgpack"),
        (msgpack.packb([1, 2]), "not a message envelope"),
        (_tamper(GOOD, type="Nope"), "unknown message type"),
        (_tamper(GOOD, version=99), "schema version 99"),
        (_tamper(GOOD, seq=-1), "bad sequence number"),
        (_tamper(GOOD, stamp_s=math.nan), "bad stamp"),
        (_tamper(GOOD, body__yaw_rate_radps=math.nan), "not finite"),
        (_tamper(GOOD, body__yaw_rate_radps=99.0), "outside"),
        (_tamper(GOOD, body__yaw_rate_radps="fast"), "expected float"),
        (_tamper(GOOD, body__extra=1), "fields"),
        (_tamper(GOOD, body__linear_mps_body={"dtype": "<f8", "shape": [4], "data": bytes(32)}), "shape"),
        (_tamper(GOOD, body__linear_mps_body={"dtype": "<f4", "shape": [3], "data": bytes(12)}), "dtype"),
        (
            _tamper(GOOD, body__linear_mps_body={"dtype": "<f8", "shape": [3], "data": bytes(8)}),
            "do not fill",
        ),
        (
            _tamper(
                GOOD,
                body__linear_mps_body={
                    "dtype": "<f8",
                    "shape": [3],
                    "data": np.array([0, np.inf, 0]).tobytes(),
                },
            ),
            "NaN or infinity",
        ),
    ],
)
def test_malformed_messages_are_refused_with_their_reason(data: bytes, reason: str) -> None:
    with pytest.raises(BadMessage, match=reason):
        decode("abyss/x/onboard/cmd/vehicle_velocity", data)


SCENE = SceneUpdate(
    kind="delta",
    scene_seq=3,
    resolution_m=0.1,
    octree=b"# Octomap OcTree binary\n" * 40,
    colors=np.full((50, 3), 136, np.uint8),
    sim_time_s=2.0,
    stream_id=7,
)
# a frame header (single segment, an 8-byte content size) announcing 1 TiB, then an empty last block
BOMB = ZSTD_MAGIC + b"\xe0" + (2**40).to_bytes(8, "little") + b"\x01\x00\x00"


def _frame(content: bytes) -> bytes:
    """A zstd frame of `content` with the codec's dictionary."""
    return zstandard.ZstdCompressor(
        dict_data=zstandard.ZstdCompressionDict(ZSTD_DICTIONARY, dict_type=zstandard.DICT_TYPE_RAWCONTENT)
    ).compress(content)


def test_the_scene_stream_goes_compressed_and_comes_back_whole() -> None:
    wire = encode(SCENE, 3, 1.0)
    assert wire.startswith(ZSTD_MAGIC) and len(wire) < 0.3 * len(msgpack.packb(msgpack.unpackb(unwrap(wire))))
    back = decode("k", wire, SceneUpdate).message
    assert isinstance(back, SceneUpdate) and back.octree == SCENE.octree
    assert np.array_equal(back.colors, SCENE.colors) and abs(wire_bytes(SCENE) - len(wire)) <= 8  # seq, stamp
    assert not encode(GOOD, 0, 1.0).startswith(ZSTD_MAGIC)  # only the classes that say so


@pytest.mark.parametrize(
    ("data", "reason"),
    [
        (ZSTD_MAGIC + b"\x00" * 3, "a zstd frame of -1 bytes"),  # no content size said: refused too
        (encode(SCENE, 0, 1.0)[:-6], "does not decompress"),  # cut short
        (BOMB, "a zstd frame of 1099511627776 bytes"),  # refused before anything is allocated
        (_frame(b"\x85" + bytes(100)), "not a message envelope|not msgpack"),
    ],
)
def test_bad_frames_are_refused_with_their_reason(data: bytes, reason: str) -> None:
    with pytest.raises(BadMessage, match=reason):
        decode("abyss/x/vessel/scene", data)


def test_wrong_type_on_a_key_is_refused() -> None:
    with pytest.raises(BadMessage, match="expected Telemetry"):
        decode("k", encode(GOOD, 0, 1.0), Telemetry)


def test_invalid_values_are_refused_at_construction() -> None:
    with pytest.raises(BadInput, match="unit quaternion"):
        NavState(np.zeros(3), np.array([1.0, 1.0, 0, 0]), np.zeros(3), np.zeros(3), 0.0)
    with pytest.raises(BadInput, match="mode"):
        Telemetry(
            np.zeros(3),
            0.0,
            "flying",
            -1,
            0,
            0,
            np.zeros(3),
            0.0,
            "idle",
            -1,
            np.zeros(3),
            0.0,
            np.zeros(3),
            np.array([1.0, 0, 0, 0]),
            np.zeros(6),
            "",
            0,
            0.0,
        )
    with pytest.raises(BadInput, match="unit quaternion"):
        ArmGoal(1, np.zeros(3), np.array([0.5, 0.0, 0.0, 0.0]))


def test_telemetry_carries_the_attitude_velocity_and_effort_its_defaults_at_rest() -> None:
    rest = sample_telemetry()
    assert np.array_equal(rest.orientation_wxyz_world, [1.0, 0.0, 0.0, 0.0])
    assert not rest.velocity_mps_body.any() and not rest.effort_body.any()
    turned = np.array([math.cos(0.2), 0.0, 0.0, math.sin(0.2)])
    moving = dataclasses.replace(
        rest,
        orientation_wxyz_world=turned,
        velocity_mps_body=np.array([0.4, -0.1, 0.05]),
        effort_body=np.array([0.8, -0.2, 0.1, -1.0]),
    )
    back = decode("k", encode(moving, 0, 1.0), Telemetry).message
    assert np.array_equal(back.orientation_wxyz_world, turned)
    assert np.array_equal(back.velocity_mps_body, [0.4, -0.1, 0.05])
    assert np.array_equal(back.effort_body, [0.8, -0.2, 0.1, -1.0])
    with pytest.raises(BadInput, match="unit quaternion"):
        dataclasses.replace(rest, orientation_wxyz_world=np.array([0.5, 0.0, 0.0, 0.0]))
    with pytest.raises(BadInput, match="effort_body"):
        dataclasses.replace(rest, effort_body=np.array([1.5, 0.0, 0.0, 0.0]))


# -- every message type, random bodies ---------------------------------------------------
# what msgpack can carry, nested a little: each field of a body is drawn from it, or, for an array
# field, from array maps of random dtype, shape and bytes (most of the right dtype and dimensions,
# so that the draws reach the range, finiteness and per-message checks)
WIRE_SCALARS = (
    st.none()
    | st.booleans()
    | st.integers(-(2**63), 2**64 - 1)
    | st.floats()
    | st.text(max_size=8)
    | st.binary(max_size=16)
)
WIRE_VALUES = st.recursive(
    WIRE_SCALARS,
    lambda inner: (
        st.lists(inner, max_size=4)
        | st.dictionaries(st.text(max_size=4) | st.binary(max_size=2), inner, max_size=4)
    ),
    max_leaves=8,
)


@st.composite
def array_maps(draw: st.DrawFn, meta: dict) -> object:
    """An array map as `encode` writes one, of the field's dtype or another, of its dimensions or
    others, its data random bytes or, often, plausible values (to reach the range checks)."""
    dims = [d if d is not None and draw(st.booleans()) else draw(st.integers(0, 4)) for d in meta["shape"]]
    shape = draw(st.sampled_from([dims, dims, dims[:-1], [*dims, 1], []]))
    dtype = draw(st.sampled_from([meta["wire_str"], meta["wire_str"], "<f4", "|u1", "<i8"]))
    size = math.prod(shape)
    if dtype == meta["wire_str"] and draw(st.booleans()):
        values = draw(st.lists(st.floats(-2.0, 2.0) | st.floats(), min_size=size, max_size=size))
        if meta["dtype"].kind != "f":  # whole numbers, in the type's range
            values = [float(np.clip(round(v), 0, 255)) if math.isfinite(v) else 0.0 for v in values]
        data = np.array(values).astype(meta["wire_dtype"]).tobytes()
    else:
        data = draw(st.binary(max_size=64))
    return {"dtype": dtype, "shape": shape, "data": data} if draw(st.integers(0, 4)) else draw(WIRE_VALUES)


def plausible(kind: object, meta: Mapping[str, object]) -> st.SearchStrategy[object]:
    """Values of a field's own type, often within its range or choices."""
    if kind is float:
        return st.floats(-2.0, 2.0) | st.floats()
    if kind is int:
        return st.integers(-2, 10)
    if kind is bool:
        return st.booleans()
    if kind is str:
        return st.sampled_from(tuple(meta.get("choices") or ("",))) | st.text(max_size=8)  # type: ignore[arg-type]
    if kind is bytes:
        return st.binary(max_size=32)
    return st.lists(st.text(max_size=4), max_size=3) | st.dictionaries(st.text(max_size=6), st.floats())


@st.composite
def bodies(draw: st.DrawFn) -> tuple[str, bytes]:
    """A message type's name and an envelope of it whose body's fields are random."""
    cls = draw(st.sampled_from(sorted(MESSAGES.values(), key=lambda c: c.TYPE)))
    schema, hints = schema_of(cls), typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    body = {
        name: draw(array_maps(schema.arrays[name]))
        if name in schema.arrays
        else draw(plausible(hints[name], fields[name].metadata) | WIRE_VALUES)
        for name, _ in schema.checks
    }
    if draw(st.booleans()) and body:  # a field missing, or one too many
        body.pop(draw(st.sampled_from(sorted(body)))) if draw(st.booleans()) else body.update(extra=1)
    envelope = {"type": cls.TYPE, "version": cls.VERSION, "seq": 0, "stamp_s": 1.0, "body": body}
    data = msgpack.packb(envelope, use_bin_type=True)
    if cls.COMPRESSED and draw(st.booleans()):
        data = _frame(data)
    return cls.TYPE, data


@given(case=bodies())
def test_random_bodies_of_every_message_type_decode_or_are_refused(case: tuple[str, bytes]) -> None:
    """Nothing from the network raises anything but BadMessage: every field is checked (a string
    where a float goes, an array map of another dtype or shape, a dict for a list) before numpy or
    a message's own checks see it."""
    name, data = case
    try:
        received = decode("k", data, MESSAGES[name])
    except BadMessage as exc:
        assert exc.key == "k" and exc.reason
    else:
        assert isinstance(received, Received) and name == received.message.TYPE
