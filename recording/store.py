"""The bus recording of a run: what each station sent and received, on every data key, in
RUN_DIR/record/<station>.mcap; the testbed's observation keys (truth, link statistics, status)
in RUN_DIR/record/testbed.mcap.

Each file is an MCAP file (profile `abyss`) that `mcap` and Foxglove list: one channel per key
and direction (`sent`: at the station's egress, before its link; `received`: as the station's bus
took it off the wire, after the link's delay, loss and corruption; `rejected`: bytes the station
dropped as malformed, with the reason; `observed`: a testbed key), the abyss message as its
msgpack bytes (`interface.messages`), `log_time` the recording station's wall clock, `publish_time`
the sender's stamp, `sequence` the sender's. Records are written one by one, unchunked, and
flushed every `FLUSH_PERIOD_S`: a killed station's file reads up to its last flush
(`read_file` says where it stops). Bounded: a level (`none`, `control`: what is not bulk, `all`)
and a rate cap per key and direction (a token bucket; what it skips is counted).

This module writes the files; `recording.reader` reads them back."""

from __future__ import annotations

import json
import queue
import threading
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import msgpack
from mcap.writer import Writer

from abyss.common.errors import AbyssError, ConfigError
from abyss.config.system import RECORD_LEVELS
from abyss.interface import keys
from abyss.interface.messages import MESSAGES, unwrap
from abyss.timing.clock import WALL, Clock

RECORD_DIR = "record"  # in the run directory
TESTBED = "testbed"  # the file of the supervisor's observation keys
FORMAT_VERSION = 1  # of this layout: channels, metadata, the rejected records
FLUSH_PERIOD_S = 0.5
MESSAGE_ENCODING = "msgpack"  # the envelope of interface.messages
REJECTED_ENCODING = "abyss-rejected"  # msgpack {reason, payload}


class RecordingError(AbyssError):
    """A recording that cannot be read as asked: missing, truncated where it must not be, too old."""

    def __init__(self, path: Path, reason: str, fix: str) -> None:
        super().__init__(f"{path}: {reason}; {fix}")
        self.path = path


def free_recording_path(directory: Path, station: str) -> Path:
    """`<station>.mcap` in `directory`, or, for a restarted station, `<station>-<life>.mcap`: each
    life of a station keeps its own file."""
    path, life = directory / f"{station}.mcap", 1
    while path.exists():
        path, life = directory / f"{station}-{life}.mcap", life + 1
    return path


def recorded(level: str, spec: keys.KeySpec) -> bool:
    """Whether `level` records the data key `spec`."""
    return level == "all" or (level == "control" and spec.priority != "bulk")


class _Bucket:
    """A token bucket of `rate_hz` with two seconds of burst: a key's messages beyond its cap are
    skipped, never those of a key at its cap whose messages come in bursts (a camera's clouds).
    On the station's clock: with simulated time, the cap is per simulated second."""

    def __init__(self, rate_hz: float, clock: Clock = WALL) -> None:
        self.rate_hz, self.capacity, self.clock = rate_hz, max(2.0, 2.0 * rate_hz), clock
        self.tokens, self.t_s = self.capacity, clock.now_s()

    def take(self) -> bool:
        now_s = self.clock.now_s()
        self.tokens = min(self.capacity, self.tokens + (now_s - self.t_s) * self.rate_hz)
        self.t_s = now_s
        if self.tokens < 1.0:
            return False
        self.tokens -= 1.0
        return True


@dataclass(frozen=True)
class Caps:
    """Per key and direction [messages/s]: `bulk_hz` for best-effort bulk keys (images, clouds),
    `max_hz` for the rest. A reliable stream (the scene's deltas) is capped at `max_hz` only: a
    skipped delta would leave every later one without its base."""

    max_hz: float = 50.0
    bulk_hz: float = 2.0

    def of(self, key: str) -> float:
        spec = data_spec(key)
        bulk = spec is not None and spec.priority == "bulk" and spec.reliability == "best-effort"
        return self.bulk_hz if bulk else self.max_hz


def data_spec(key: str) -> keys.KeySpec | None:
    """The data key `abyss/<system>/<station>/<topic>` is, or None (a testbed key)."""
    parts = key.split("/", 3)
    if len(parts) < 4:
        return None
    try:
        return keys.spec(parts[2], parts[3])
    except AbyssError:
        return None


class Recorder:
    """Writes one station's (or the testbed's) recording from any thread: the callers only queue,
    a writer thread encodes and flushes."""

    def __init__(
        self, path: Path, station: str, system: str, level: str, caps: Caps = Caps(), clock: Clock = WALL
    ) -> None:
        self.clock = clock
        if level not in RECORD_LEVELS:
            raise ConfigError("record.level", f"{level!r} not one of {', '.join(RECORD_LEVELS)}")
        self.path, self.station, self.level, self.caps = path, station, level, caps
        self.counts: Counter[str] = Counter()  # recorded, per direction
        self.skipped: Counter[str] = Counter()  # over a key's cap, per key
        self.bytes_written = 0
        self.writer_cpu_s = 0.0  # the writer thread's CPU time, as of its latest flush
        self._buckets: dict[tuple[str, str], _Bucket] = {}
        self._queue: queue.SimpleQueue[_Item | threading.Event | None] = queue.SimpleQueue()
        self._lock = threading.Lock()
        path.parent.mkdir(parents=True, exist_ok=True)
        self._file: IO[bytes] = path.open("wb")
        self._writer = Writer(self._file, use_chunking=False, use_statistics=True)
        self._writer.start(profile="abyss", library="abyss recording")
        self._writer.add_metadata(
            "abyss",
            {
                "format_version": str(FORMAT_VERSION),
                "station": station,
                "system": system,
                "level": level,
                "max_rate_hz": str(caps.max_hz),
                "bulk_max_rate_hz": str(caps.bulk_hz),
                "messages": json.dumps({name: cls.VERSION for name, cls in MESSAGES.items()}),
            },
        )
        self._channels: dict[tuple[str, str], int] = {}
        self._schemas: dict[str, int] = {}
        self._thread = threading.Thread(target=self._write_loop, name=f"recorder {station}", daemon=True)
        self._thread.start()

    def wants(self, key: str) -> bool:
        spec = data_spec(key)
        return self.level != "none" and (spec is None or recorded(self.level, spec))

    def add(
        self,
        direction: str,
        key: str,
        payload: bytes,
        reason: str = "",
        envelope: tuple[int, float] | None = None,
    ) -> None:
        """Queue one message as this station `direction` it, now; skipped over its key's cap.
        `envelope`: its sequence number and stamp where the caller has them (the bus: the writer
        then need not unpack a frame's megabyte to find them)."""
        if not self.wants(key):
            return
        with self._lock:
            bucket = self._buckets.get((key, direction))
            if bucket is None:
                bucket = self._buckets[(key, direction)] = _Bucket(self.caps.of(key), self.clock)
            if not bucket.take():
                self.skipped[f"{direction} {key}"] += 1
                return
        self._queue.put((direction, key, payload, time.time(), reason, envelope))

    def status(self) -> dict[str, Any]:
        with self._lock:
            return {
                "file": str(self.path),
                "level": self.level,
                "recorded": dict(self.counts),
                "skipped_over_cap": dict(self.skipped),
                "bytes": self.bytes_written,
                "writer_cpu_s": round(self.writer_cpu_s, 3),
            }

    def flush(self, timeout_s: float = 10.0) -> None:
        """Write what is queued and flush the file (lockstep, before a hold: a station killed in
        it leaves every message it recorded)."""
        written = threading.Event()
        self._queue.put(written)
        written.wait(timeout_s)

    def close(self) -> None:
        """Write what is queued, then the MCAP summary (a file without it reads all the same)."""
        self._queue.put(None)
        self._thread.join(timeout=5.0)

    # -- the writer thread ---------------------------------------------------------------
    def _channel(self, direction: str, key: str) -> int:
        channel = self._channels.get((key, direction))
        if channel is not None:
            return channel
        spec = data_spec(key)
        message = spec.message if spec is not None else ""
        schema = 0
        if direction != "rejected" and message:
            if message not in self._schemas:
                self._schemas[message] = self._writer.register_schema(
                    message, "abyss-message", json.dumps({"version": MESSAGES[message].VERSION}).encode()
                )
            schema = self._schemas[message]
        metadata = {
            "direction": direction,
            "station": self.station,
            "message": message,
            "hop": spec.hop if spec is not None else "",
            "publisher": key.split("/")[2] if key.count("/") >= 2 else "",
        }
        channel = self._channels[(key, direction)] = self._writer.register_channel(
            key, REJECTED_ENCODING if direction == "rejected" else MESSAGE_ENCODING, schema, metadata
        )
        return channel

    def _write_loop(self) -> None:
        next_flush_s = time.monotonic() + FLUSH_PERIOD_S
        while True:
            try:
                item = self._queue.get(timeout=FLUSH_PERIOD_S)
            except queue.Empty:
                item = ("", "", b"", 0.0, "", None)  # nothing came: only the flush is due
            if item is None:
                break
            if isinstance(item, threading.Event):
                self._file.flush()
                item.set()
                continue
            if item[0]:
                self._write(*item)
            if time.monotonic() >= next_flush_s:
                self._file.flush()
                next_flush_s = time.monotonic() + FLUSH_PERIOD_S
                self.writer_cpu_s = time.thread_time()
        self._writer.finish()
        self._file.close()
        self.writer_cpu_s = time.thread_time()

    def _write(
        self,
        direction: str,
        key: str,
        payload: bytes,
        recorded_s: float,
        reason: str,
        envelope: tuple[int, float] | None,
    ) -> None:
        seq, sent_s = 0, recorded_s
        if direction == "rejected":
            payload = msgpack.packb({"reason": reason, "payload": payload}, use_bin_type=True)
        else:
            seq, sent_s = envelope or envelope_of(payload)
        self._writer.add_message(
            self._channel(direction, key),
            log_time=round(recorded_s * 1e9),
            data=payload,
            publish_time=round(sent_s * 1e9),
            sequence=seq % 2**32,
        )
        with self._lock:
            self.counts[direction] += 1
            self.bytes_written += len(payload)


# direction, key, payload, when recorded [s], a rejection's reason, (seq, stamp [s]) if known
_Item = tuple[str, str, bytes, float, str, tuple[int, float] | None]


def envelope_of(payload: bytes) -> tuple[int, float]:
    """The sequence number and the sender's stamp [s] of an encoded message (0 and 0.0 if the bytes
    hold none)."""
    try:
        envelope = msgpack.unpackb(unwrap(payload), raw=False)
        return int(envelope["seq"]), float(envelope["stamp_s"])
    except Exception:  # bytes that decode to no envelope: a rejected message's own
        return 0, 0.0
