"""The codec: round trips, and every kind of malformed input refused with its reason."""

from __future__ import annotations

import math

import msgpack
import numpy as np
import pytest
import zstandard
from hypothesis import given
from hypothesis import strategies as st

from abyss.common.errors import BadMessage
from abyss.common.messages import (
    ZSTD_DICTIONARY,
    ZSTD_MAGIC,
    ArmGoal,
    NavState,
    SceneUpdate,
    Telemetry,
    VelocityRef,
    Waypoints,
    decode,
    encode,
    unwrap,
    wire_bytes,
)

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
    back = decode("k", wire, "SceneUpdate").message
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
        decode("k", encode(GOOD, 0, 1.0), expected="Telemetry")


def test_invalid_values_are_refused_at_construction() -> None:
    with pytest.raises(ValueError, match="unit quaternion"):
        NavState(np.zeros(3), np.array([1.0, 1.0, 0, 0]), np.zeros(3), np.zeros(3), 0.0)
    with pytest.raises(ValueError, match="mode"):
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
    with pytest.raises(ValueError, match="unit quaternion"):
        ArmGoal(1, np.zeros(3), np.array([0.5, 0.0, 0.0, 0.0]))
