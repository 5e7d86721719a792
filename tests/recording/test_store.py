"""The bus recording's file, without Zenoh: what a recorder writes reads back, with its caps, a killed
station's file up to where it stopped, and a recording of another format or schema refused with the fix."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from abyss.interface.messages import JointState, NavState, PointCloud, encode
from abyss.recording import store
from abyss.recording.reader import open_recording, read_file
from abyss.recording.store import Caps, Recorder, RecordingError

SYSTEM = "t"
NAV = "abyss/t/simulation/nav"
CLOUD = "abyss/t/onboard/cloud"


def nav(i: int) -> bytes:
    message = NavState(np.array([i, 0.0, -7.0]), np.array([1.0, 0, 0, 0]), np.zeros(3), np.zeros(3), 0.05 * i)
    return encode(message, i, time.time() - 0.1)


def cloud(i: int) -> bytes:
    import zlib

    message = PointCloud("depth", 1, 0.01, np.zeros(3), np.zeros(3), zlib.compress(bytes(9)), 0.5 * i)
    return encode(message, i, time.time())


def write(path: Path, count: int, caps: Caps | None = None) -> Recorder:
    recorder = Recorder(path, "onboard", SYSTEM, "all", caps or Caps())
    for i in range(count):
        recorder.add("received", NAV, nav(i))
        recorder.add("sent", CLOUD, cloud(i))
    recorder.add("rejected", NAV, b"\x00not msgpack", "not msgpack: bad")
    return recorder


def test_what_is_recorded_reads_back_with_both_stamps_and_the_hop(tmp_path: Path) -> None:
    recorder = write(tmp_path / "record" / "onboard.mcap", 20, Caps(max_hz=1000.0, bulk_hz=1000.0))
    recorder.close()
    f = read_file(tmp_path / "record" / "onboard.mcap")
    assert f.complete and f.read_bytes == f.size_bytes and f.station == "onboard" and f.system == SYSTEM
    received = [r for r in f.records if r.direction == "received"]
    assert [r.seq for r in received] == list(range(20))
    assert all(r.hop == "rov" and r.message == "NavState" and r.publisher == "simulation" for r in received)
    assert all(0.05 < r.recorded_s - r.sent_s < 5.0 for r in received)  # the sender's stamp, then ours
    first = received[3].decode().message
    assert isinstance(first, NavState) and first.position_m_world[0] == 3.0
    sent = [r for r in f.records if r.direction == "sent"]
    assert len(sent) == 20 and all(r.hop == "tether" for r in sent)
    [rejected] = [r for r in f.records if r.direction == "rejected"]
    assert rejected.payload == b"\x00not msgpack" and rejected.reason == "not msgpack: bad"
    recording = open_recording(tmp_path)
    assert len(recording.published()) == 40 and recording.stations == {"onboard"}


def test_a_key_over_its_cap_is_skipped_and_counted(tmp_path: Path) -> None:
    recorder = write(tmp_path / "a.mcap", 50, Caps(max_hz=1000.0, bulk_hz=2.0))
    recorder.close()
    status = recorder.status()
    assert status["skipped_over_cap"] == {f"sent {CLOUD}": 50 - 4}  # two seconds of burst at 2 Hz
    assert status["recorded"]["received"] == 50
    control = Recorder(tmp_path / "b.mcap", "onboard", SYSTEM, "control")
    control.add("sent", CLOUD, cloud(0))
    control.add("received", NAV, nav(0))
    control.close()
    assert [r.key for r in read_file(tmp_path / "b.mcap").records] == [NAV]  # control leaves bulk out


def test_a_killed_station_s_file_reads_up_to_where_it_stopped(tmp_path: Path) -> None:
    path = tmp_path / "onboard.mcap"
    recorder = write(path, 30, Caps(max_hz=1000.0, bulk_hz=1000.0))
    recorder.close()
    whole = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(whole[: len(whole) // 2])  # a station killed mid-write: no summary, half a record
    f = read_file(cut)
    assert not f.complete and 0 < len(f.records) < 61
    assert [r.seq for r in f.records if r.direction == "received"] == list(
        range(len([r for r in f.records if r.direction == "received"]))
    )


def test_another_format_or_an_older_schema_is_refused_with_the_fix(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    with pytest.raises(RecordingError, match=r"no recording.*--record all"):
        open_recording(tmp_path)
    monkeypatch.setattr(store, "FORMAT_VERSION", 0)
    write(tmp_path / "record" / "onboard.mcap", 1).close()
    monkeypatch.undo()
    with pytest.raises(
        RecordingError,
        match=r"onboard\.mcap: recording format version 0, this abyss "
        "reads 1; record the run again",
    ):
        open_recording(tmp_path)
    monkeypatch.setattr(JointState, "VERSION", 0)  # a message's schema changed since the recording
    write(tmp_path / "old.mcap", 1).close()
    monkeypatch.undo()
    with pytest.raises(
        RecordingError,
        match=r"old\.mcap: messages of an older schema: JointState v0 "
        rf"\(now v{JointState.VERSION}\)",
    ):
        read_file(tmp_path / "old.mcap")
    (tmp_path / "junk.mcap").write_bytes(b"not an mcap file at all")
    with pytest.raises(RecordingError, match="not an abyss recording"):
        read_file(tmp_path / "junk.mcap")
