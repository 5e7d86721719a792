"""Reading a run's bus recording back (`recording.store` writes it): each station's MCAP file
up to where a killed station stopped writing, checked for its format and its messages' schema
versions, and the whole run's records by station, direction, publisher or time."""

from __future__ import annotations

import json
import logging
import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import mcap.exceptions
import msgpack
from mcap.records import Channel, Metadata
from mcap.records import Message as McapMessage
from mcap.stream_reader import StreamReader

from abyss.common.errors import BadMessage
from abyss.interface.messages import MESSAGES, Message, Received, decode
from abyss.recording.store import (
    FORMAT_VERSION,
    RECORD_DIR,
    REJECTED_ENCODING,
    TESTBED,
    RecordingError,
    data_spec,
)

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Record:
    """One recorded message as `station` saw it: `sent_s` the sender's stamp, `recorded_s` when the
    recording station sent it or took it off the wire (its wall clock)."""

    station: str
    direction: str
    key: str
    hop: str
    message: str  # the type name; '' for a testbed key read without one, or rejected bytes
    seq: int
    sent_s: float
    recorded_s: float
    payload: bytes
    reason: str = ""  # rejected only

    @property
    def publisher(self) -> str:
        return self.key.split("/")[2]

    @property
    def topic(self) -> str:
        """`<publisher>/<topic>`: the key without `abyss/<system>/`."""
        return self.key.split("/", 2)[2]

    def decode(self) -> Received[Message]:
        """The record's message, checked to be of the type it was recorded as (a name, as the file
        writes it; none for a testbed key read without one)."""
        return decode(self.key, self.payload, MESSAGES[self.message] if self.message else None)


@dataclass
class RecordingFile:
    path: Path
    station: str
    system: str
    level: str
    records: list[Record]
    complete: bool  # its summary was written: the station closed it
    read_bytes: int  # where reading stopped
    size_bytes: int


def read_file(path: Path) -> RecordingFile:
    """Every record of one station's file, up to where a killed station stopped writing."""
    if not path.is_file():
        raise RecordingError(path, "no such recording", "record a run with `abyss up --record all`")
    size = path.stat().st_size
    records: list[Record] = []
    channels: dict[int, Channel] = {}
    meta: dict[str, str] = {}
    complete = False
    with path.open("rb") as f:
        reader = StreamReader(f, skip_magic=False)
        try:
            for record in reader.records:
                if isinstance(record, Metadata) and record.name == "abyss":
                    meta = dict(record.metadata)
                    _check_version(path, meta)
                elif isinstance(record, Channel):
                    channels[record.id] = record
                elif isinstance(record, McapMessage):
                    records.append(_record_of(channels[record.channel_id], record))
                elif type(record).__name__ == "Footer":
                    complete = True
        except (mcap.exceptions.McapError, EOFError, ValueError, KeyError, OSError, struct.error) as exc:
            log.info("%s: read up to byte %d of %d (%s)", path, f.tell(), size, exc)
        read_bytes = f.tell()
    if not meta:
        raise RecordingError(
            path,
            "not an abyss recording (no abyss metadata at its start)",
            "give the run directory of an `abyss up` with --record control or all",
        )
    return RecordingFile(
        path, meta["station"], meta["system"], meta["level"], records, complete, read_bytes, size
    )


def _check_version(path: Path, meta: dict[str, str]) -> None:
    version = meta.get("format_version", "?")
    if version != str(FORMAT_VERSION):
        raise RecordingError(
            path,
            f"recording format version {version}, this abyss reads {FORMAT_VERSION}",
            "record the run again with this abyss, or read it with the abyss that made it",
        )
    try:
        recorded_versions = json.loads(meta.get("messages", "{}"))
    except ValueError:
        recorded_versions = {}
    older = sorted(
        f"{name} v{v} (now v{MESSAGES[name].VERSION})"
        for name, v in recorded_versions.items()
        if name in MESSAGES and v != MESSAGES[name].VERSION
    )
    if older:
        raise RecordingError(
            path,
            f"messages of an older schema: {', '.join(older)}",
            "record the run again with this abyss, or read it with the abyss that made it",
        )


def _record_of(channel: Channel, message: McapMessage) -> Record:
    meta = channel.metadata
    payload, reason = message.data, ""
    if channel.message_encoding == REJECTED_ENCODING:
        rejected = msgpack.unpackb(message.data, raw=False)
        payload, reason = rejected["payload"], rejected["reason"]
    return Record(
        meta.get("station", ""),
        meta.get("direction", ""),
        channel.topic,
        meta.get("hop", ""),
        meta.get("message", ""),
        message.sequence,
        message.publish_time / 1e9,
        message.log_time / 1e9,
        payload,
        reason,
    )


@dataclass
class Recording:
    """A run's whole recording: each station's file and the testbed's."""

    run_dir: Path
    files: list[RecordingFile] = field(default_factory=list)  # a restarted station's lives in order

    @property
    def system(self) -> str:
        return self.files[0].system

    @property
    def stations(self) -> set[str]:
        """The stations recorded (the testbed's observation file not among them)."""
        return {f.station for f in self.files} - {TESTBED}

    def records(self, stations: tuple[str, ...] = (), directions: tuple[str, ...] = ()) -> list[Record]:
        """Records of these stations' files in these directions (all if empty), by recorded time."""
        chosen = [
            r
            for f in self.files
            if not stations or f.station in stations
            for r in f.records
            if not directions or r.direction in directions
        ]
        return sorted(chosen, key=lambda r: r.recorded_s)

    def published(self, publishers: tuple[str, ...] = ()) -> list[Record]:
        """Each message of these publishers (all if empty) once, by its sender's stamp: the copy the
        publisher recorded at its egress, or, for a station that was not recorded (an external one),
        the first copy a receiver recorded."""
        chosen: dict[tuple[str, int, float], Record] = {}
        for r in self.records(directions=("sent", "received")):
            spec = data_spec(r.key)
            if spec is None or (publishers and spec.station not in publishers):
                continue
            if spec.station in self.stations and r.direction == "received":
                continue
            chosen.setdefault((r.key, r.seq, r.sent_s), r)
        return sorted(chosen.values(), key=lambda r: r.sent_s)

    def observed(self) -> list[Record]:
        return self.records(stations=(TESTBED,), directions=("observed",))

    def messages(self, records: list[Record]) -> Iterator[tuple[Record, Message]]:
        """Each record with its message; records that do not decode (rejected ones) are left out."""
        for r in records:
            try:
                yield r, r.decode().message
            except BadMessage:
                continue


def open_recording(run_dir: Path) -> Recording:
    """The recording of `run_dir`, with an error that names the fix if there is none."""
    folder = run_dir / RECORD_DIR
    paths = sorted(folder.glob("*.mcap"), key=lambda p: p.stat().st_mtime) if folder.is_dir() else []
    if not paths:
        raise RecordingError(
            folder,
            "no recording",
            "the run was made with --record none, or by an abyss "
            "before recording; run `abyss up --record all` (the default)",
        )
    recording = Recording(run_dir)
    recording.files = [read_file(path) for path in paths]
    return recording
