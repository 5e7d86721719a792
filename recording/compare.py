"""How a replay's live stations answered the recorded inputs, against what they sent in the
recording (`abyss replay RUN_DIR --as ... --compare`): per key, the rate, the latency at the
receiver, and each numeric field's difference.

Messages are paired by simulated time where they carry it (the replayed simulation's clock is the
recorded one), else by their time since the run's start (the replay's start in the new run), with
those within `PAIR_WINDOW_S`; commands (event keys) in order. Only the time the recording spans
counts: past it, the live stations have no inputs. `field_diffs` says when a field differs: the
link's own randomness moves messages in time, which this absorbs, while a changed gain moves the
values themselves."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from abyss.interface import keys
from abyss.interface.messages import Message, ReplayStart
from abyss.recording.reader import Record, Recording

PAIR_WINDOW_S = 0.25
FLOOR = 1e-6
# ids are new in every run; the time is what pairs messages; the vessel's silence of shore measures
# the satellite link itself (its losses and jitter), not the station's behaviour
NOT_COMPARED = {
    "command_id",
    "arm_command_id",
    "boot_id",
    "scene_seq",
    "stream_id",
    "sim_time_s",
    "shore_silence_s",
}


@dataclass
class FieldDiff:
    name: str
    p95_abs: float  # of the paired differences
    shift: float  # the largest difference of the runs' quantiles
    scale: float  # of the recorded values: their spread or their magnitude
    differs: bool


@dataclass
class KeyDiff:
    key: str  # <publisher>/<topic>
    count: tuple[int, int]  # recorded, replayed
    rate_hz: tuple[float, float]
    latency_ms: tuple[float, float]  # p50 at the receiver
    paired: int
    fields: list[FieldDiff] = field(default_factory=list)

    @property
    def differs(self) -> bool:
        return any(f.differs for f in self.fields)

    def row(self) -> dict[str, Any]:
        return {
            "key": self.key,
            "count": list(self.count),
            "rate_hz": [round(r, 2) for r in self.rate_hz],
            "latency_ms": [round(v, 1) for v in self.latency_ms],
            "paired": self.paired,
            "differs": self.differs,
            "fields": {
                f.name: {"p95_abs": f.p95_abs, "shift": f.shift, "scale": f.scale, "differs": f.differs}
                for f in self.fields
            },
        }


def numeric_fields(message: Message) -> dict[str, np.ndarray]:
    """A message's numbers, flattened per field; strings as 0/1 against nothing (compared for equality)."""
    out: dict[str, np.ndarray] = {}
    for name, value in vars(message).items():
        if name in NOT_COMPARED or isinstance(value, (bytes, dict, tuple)):
            continue
        if isinstance(value, bool):
            value = float(value)
        if isinstance(value, (int, float)):
            out[name] = np.array([float(value)])
        elif isinstance(value, np.ndarray) and value.dtype.kind in "fiu" and 0 < value.size <= 64:
            out[name] = value.astype(float).ravel()
    return out


def text_fields(message: Message) -> dict[str, str]:
    return {n: v for n, v in vars(message).items() if isinstance(v, str) and n not in NOT_COMPARED}


def start_of(recording: Recording) -> float:
    """The run's time zero: a replay's start where it has one, else its first message."""
    for record, message in recording.messages(recording.observed()):
        if isinstance(message, ReplayStart) and record.key.endswith("/replay"):
            return message.start_s
    return min(r.sent_s for r in recording.published())


class Series:
    """One key's messages of one run: times for pairing, numbers and texts per field."""

    def __init__(self, items: list[tuple[Record, Message]], start_s: float) -> None:
        self.items = items
        self.by_sim = bool(items) and all(hasattr(m, "sim_time_s") for _, m in items)
        self.t_s = np.array(
            [
                m.sim_time_s if self.by_sim else r.sent_s - start_s  # type: ignore[attr-defined]
                for r, m in items
            ]
        )
        sent_s = [r.sent_s for r, _ in items]
        self.duration_s = max(sent_s) - min(sent_s) if items else 0.0

    def within(self, other: Series) -> Series:
        """The messages of the time both runs span: a replay outlasts its recording (a live shore
        finishes later), a live station goes on after the replayed inputs stop."""
        if not self.items or not other.items:
            return self
        lo_s = max(self.t_s.min(), other.t_s.min()) - PAIR_WINDOW_S
        hi_s = min(self.t_s.max(), other.t_s.max()) + PAIR_WINDOW_S
        inside = (self.t_s >= lo_s) & (self.t_s <= hi_s)
        series = Series([item for item, keep in zip(self.items, inside, strict=True) if keep], 0.0)
        series.t_s = self.t_s[inside]
        return series

    def rate_hz(self) -> float:
        return (len(self.items) - 1) / self.duration_s if len(self.items) > 1 and self.duration_s > 0 else 0.0

    def neighbours(self, other: Series) -> list[tuple[int, np.ndarray]]:
        """Per message here, the indices of `other`'s messages within `PAIR_WINDOW_S` of it in time
        (those that have any). An event key's messages (commands) pair in order instead."""
        out = []
        for i, t in enumerate(self.t_s):
            near = np.flatnonzero(np.abs(other.t_s - t) <= PAIR_WINDOW_S)
            if len(near):
                out.append((i, near))
        return out


def latency_ms(recording: Recording, key_topic: str) -> float:
    """The median time from the sender's stamp to the receiver's bus, of one key."""
    delays = [
        r.recorded_s - r.sent_s for r in recording.records(directions=("received",)) if r.topic == key_topic
    ]
    return 1e3 * float(np.median(delays)) if delays else math.nan


def compare(
    recorded: Recording, replayed: Recording, publishers: Sequence[str], tolerance: float = 0.1
) -> list[KeyDiff]:
    """Per data key of `publishers` (the live stations of the replay), how the replay differs."""
    starts = start_of(recorded), start_of(replayed)
    span_s = max(r.sent_s for r in recorded.published()) - starts[0]  # past it, a replay has no inputs
    diffs = []
    for spec in keys.KEYS:
        if spec.station not in publishers:
            continue
        topic = f"{spec.station}/{spec.topic}"
        a, b = (
            Series(
                [
                    (r, m)
                    for r, m in run.messages(run.published((spec.station,)))
                    if r.topic == topic and r.sent_s - start <= span_s
                ],
                start,
            )
            for run, start in zip((recorded, replayed), starts, strict=True)
        )
        if spec.feature and not a.items and not b.items:  # a feature neither run ran (mavlink)
            continue
        diff = KeyDiff(
            topic,
            (len(a.items), len(b.items)),
            (a.rate_hz(), b.rate_hz()),
            (latency_ms(recorded, topic), latency_ms(replayed, topic)),
            0,
        )
        if spec.rate_hz:
            a, b = a.within(b), b.within(a)
            pairs = b.neighbours(a)
        else:
            pairs = [(i, np.array([i])) for i in range(min(len(a.items), len(b.items)))]
        diff.paired = len(pairs)
        if pairs:
            diff.fields = field_diffs(a, b, pairs, tolerance)
        diffs.append(diff)
    return diffs


QUANTILES = tuple(range(5, 100, 5))


def field_diffs(
    a: Series, b: Series, pairs: list[tuple[int, np.ndarray]], tolerance: float
) -> list[FieldDiff]:
    """Per field: `p95_abs`, the 95th percentile over `b`'s messages of the smallest difference to a
    recorded message near it in time (the link's jitter moves messages, not values), and `shift`,
    the largest difference of the two runs' quantiles (a signal of random phase, a heartbeat's
    silence, differs point by point but not in distribution). Both are measured against the field's
    scale: the larger of its recorded spread and its typical magnitude. It differs when both exceed
    `tolerance` of it; a text field when its values match in fewer than 1 - `tolerance` (at least
    90 %) of the pairs and their frequencies differ by as much."""
    recorded = [numeric_fields(m) for _, m in a.items]
    replayed = [numeric_fields(m) for _, m in b.items]
    out = []
    for name, first in recorded[0].items():
        values = np.array([r[name] for r in recorded if name in r and r[name].shape == first.shape])
        news = [r[name] for r in replayed if name in r and r[name].shape == first.shape]
        deltas = [
            min(float(np.max(np.abs(recorded[j][name] - replayed[i][name]))) for j in near)
            for i, near in pairs
            if name in replayed[i] and replayed[i][name].shape == first.shape
        ]
        if not deltas:
            continue
        scale = max(
            float(np.max(np.percentile(values, 95, axis=0) - np.percentile(values, 5, axis=0))),
            float(np.sqrt(np.mean(values**2))),
            FLOOR,
        )
        shift = float(
            np.max(
                np.abs(
                    np.percentile(values, QUANTILES, axis=0)
                    - np.percentile(np.array(news), QUANTILES, axis=0)
                )
            )
        )
        p95 = float(np.percentile(deltas, 95))
        differs = p95 > tolerance * scale and shift > tolerance * scale
        out.append(FieldDiff(name, p95, shift, scale, bool(differs)))
    texts_a, texts_b = [text_fields(m) for _, m in a.items], [text_fields(m) for _, m in b.items]
    limit = max(tolerance, 0.1)
    for name in texts_a[0]:
        share = float(np.mean([all(texts_a[j][name] != texts_b[i][name] for j in near) for i, near in pairs]))
        share_shift = max(
            float(abs(np.mean([t[name] == v for t in texts_a]) - np.mean([t[name] == v for t in texts_b])))
            for v in {t[name] for t in texts_a + texts_b}
        )
        out.append(FieldDiff(name, share, share_shift, 1.0, share > limit and share_shift > limit))
    return out


def render(diffs: list[KeyDiff]) -> str:
    """The comparison as a table: one row per key, then the fields that differ."""
    rows = [f"{'key':32} {'count rec/new':>14} {'rate Hz rec/new':>16} {'latency ms rec/new':>19}  result"]
    for d in diffs:
        worst = sorted((f for f in d.fields if f.differs), key=lambda f: -f.p95_abs / f.scale)
        result = "same" if d.paired else "unpaired"
        if worst:
            result = "differs: " + ", ".join(
                f"{f.name} (p95 {f.p95_abs:.3g}, shift {f.shift:.3g} of {f.scale:.3g})" for f in worst[:3]
            )
        latency = "/".join("-" if math.isnan(v) else f"{v:.1f}" for v in d.latency_ms)
        rows.append(
            f"{d.key:32} {d.count[0]:>6}/{d.count[1]:<7} {d.rate_hz[0]:>7.2f}/{d.rate_hz[1]:<8.2f} "
            f"{latency:>19}  {result}"
        )
    return "\n".join(rows)


def differing(diffs: list[KeyDiff]) -> list[str]:
    return [d.key for d in diffs if d.differs]
