"""What the TCP comparison runs: kernel variants, cases (a profile and its workload), phases, and
what one run measured."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from abyss.config.linkprofile import LinkProfile, profile

BULK_MESSAGE_BYTES = 14_600  # ten whole model packets


@dataclass(frozen=True)
class Variant:
    """A kernel TCP: the sender's congestion control (set on its socket: a namespace may only
    default to the host's allowed ones) and net.ipv4 sysctls in both namespaces; and what shapes
    its packets: the TUN shaper, or tc/netem where the kernel has it (in UML on this machine)."""

    congestion_control: str
    sysctls: tuple[tuple[str, str], ...] = ()
    shaper: str = "tun"  # or "netem"


VARIANTS: dict[str, Variant] = {
    # closest to the textbook: Reno without SACK (so NewReno recovery), RACK, tail loss probes,
    # F-RTO or timestamps (so Karn's rule on retransmissions)
    "reno-textbook": Variant(
        "reno",
        (
            ("tcp_sack", "0"),
            ("tcp_dsack", "0"),
            ("tcp_recovery", "0"),
            ("tcp_early_retrans", "0"),
            ("tcp_frto", "0"),
            ("tcp_timestamps", "0"),
        ),
    ),
    # the kernel's loss recovery as it ships (SACK, RACK-TLP, PRR, F-RTO), Reno's window
    "reno": Variant("reno"),
    "cubic": Variant("cubic"),
    # the same through tc/netem (the third of the shapers: the emulated link is the model)
    "reno-netem": Variant("reno", shaper="netem"),
    "cubic-netem": Variant("cubic", shaper="netem"),
}
COMMON_SYSCTLS = (("tcp_no_metrics_save", "1"),)  # each connection starts afresh, as each model link


@dataclass(frozen=True)
class Stream:
    """Messages of one size, one every `interval_s`."""

    size_bytes: int
    count: int
    interval_s: float

    @property
    def phase(self) -> str:
        return f"{self.size_bytes // 1000}kB"


@dataclass(frozen=True)
class Phase:
    """Messages to send, (due [s from the start], size [bytes]) each; with `window_s`, only what
    the sender writes and the receiver reads in that window counts (a bulk transfer)."""

    name: str
    schedule: tuple[tuple[float, int], ...]
    window_s: float | None = None


@dataclass(frozen=True)
class Case:
    """A profile (with overrides) and its workload, sized to the rate TCP gets through it."""

    name: str
    profile: str
    hop: str  # whose lab addresses carry it
    bulk_s: float
    streams: tuple[Stream, ...]
    overrides: tuple[tuple[str, str], ...] = ()

    def link_profile(self, seed: int) -> LinkProfile:
        return profile(self.profile, {**dict(self.overrides), "seed": str(seed)})

    @property
    def phases(self) -> list[str]:
        return ["bulk", *(s.phase for s in self.streams)]

    def offered_bps(self, phase: str) -> float:
        """What a phase offers the link: all it can take in a bulk transfer."""
        if phase == "bulk":
            return self.link_profile(0).rate_bps
        stream = self._stream(phase)
        return stream.size_bytes * 8.0 / stream.interval_s

    def phase(self, name: str) -> Phase:
        if name == "bulk":  # more than the link can carry in the window
            count = math.ceil(self.bulk_s * self.link_profile(0).rate_bps / 8 / BULK_MESSAGE_BYTES) + 1
            return Phase(name, ((0.0, BULK_MESSAGE_BYTES),) * count, self.bulk_s)
        stream = self._stream(name)
        return Phase(name, tuple((i * stream.interval_s, stream.size_bytes) for i in range(stream.count)))

    def _stream(self, phase: str) -> Stream:
        return next(s for s in self.streams if s.phase == phase)


# Paces: about half of what TCP carries through each profile (the satellite at 5 % loss carries
# about 150 kbit/s, at 1 % about 450); each phase lasts 5 to 30 s.
CASES: dict[str, Case] = {
    c.name: c
    for c in (
        Case(
            "tether",
            "tether",
            "tether",
            8.0,
            (Stream(1_000, 200, 0.02), Stream(10_000, 100, 0.05), Stream(100_000, 20, 0.25)),
        ),
        Case(
            "satellite",
            "satellite",
            "satellite",
            20.0,
            (Stream(1_000, 100, 0.1), Stream(10_000, 20, 1.0), Stream(100_000, 4, 8.0)),
        ),
        Case(
            "satellite-1%",
            "satellite",
            "satellite",
            15.0,
            (Stream(1_000, 100, 0.1), Stream(10_000, 30, 0.5), Stream(100_000, 8, 3.0)),
            overrides=(("loss", "1%"),),
        ),
        # lone packets on a link of little jitter, one in ten lost: recovered when the timer fires
        # (RTO = SRTT + 200 ms, sooner than a probe), so their latency is the timer's
        Case("tether-10%", "tether", "tether", 8.0, (Stream(1_000, 40, 0.5),), overrides=(("loss", "10%"),)),
    )
}


@dataclass
class Run:
    """One phase, one way (the model or a kernel variant), one seed. Times from the phase's start."""

    phase: Phase
    deliveries: list[tuple[float, int, float]]  # (due_s, size_bytes, delivered_s) of each message
    originals: int  # data packets sent, each counted once
    retransmissions: int  # data packets sent again
    timeouts: int  # retransmission timer expiries
    extra: dict[str, float] = field(default_factory=dict)  # shaper and kernel counters, for the record

    def metrics(self) -> dict[str, float]:
        per_packet = {
            "retrans_per_packet": self.retransmissions / max(1, self.originals),
            "timeouts_per_packet": self.timeouts / max(1, self.originals),
            "packets": float(self.originals),
        }
        if self.phase.window_s is not None:
            window_s = self.phase.window_s
            delivered_bytes = sum(size for _, size, t_s in self.deliveries if t_s <= window_s)
            return {"goodput_bps": delivered_bytes * 8.0 / window_s, **per_packet}
        latencies_s = [delivered - due for due, _, delivered in self.deliveries]
        p50, p95 = np.percentile(latencies_s, [50, 95])
        return {"latency_p50_s": float(p50), "latency_p95_s": float(p95), **per_packet}


@dataclass(frozen=True)
class Job:
    """One run to make: `way` is "model" or a kernel variant."""

    way: str
    case: str
    phase: str
    seed: int

    def __str__(self) -> str:
        return f"{self.way} {self.case} {self.phase} seed {self.seed}"
