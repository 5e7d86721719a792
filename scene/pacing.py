"""How fast scene updates may go to shore, measured end to end as a real sender must: shore
acknowledges each update by its sequence number (`SceneAck`), and the vessel sees nothing of
the link but those acknowledgements.

- One update at most is in flight (sent, not yet acknowledged), so telemetry on the same link
  never queues behind more than one; an update unacknowledged for `ack_timeout_s` is taken as
  lost (shore asks for a snapshot after a gap).
- Each update's round trip is `rtt0 + 8 bytes / capacity`: the link's own delay plus the time
  the update takes to pass at the link's capacity. Updates alternate between a full and a half
  size (as BBR cycles its pacing gain), so that a least-squares line through the recent
  (bytes, round trip) pairs tells capacity (the slope) from delay (the intercept); jitter
  averages out of the fit.
- A token bucket filled at `share` of the capacity bounds the scene's share of the link, and an
  update is at most `HEAD_OF_LINE_S` of the capacity (16 kB at 1 Mbit/s, 8 kB in a 256 kbit/s
  storm): telemetry's wait behind one."""

from __future__ import annotations

import math
from collections import deque

import numpy as np

SMOOTHING = 0.3  # weight of a new capacity fit
HEAD_OF_LINE_S = 0.25  # an update takes at most this long of the link [s]
MIN_UPDATE_BYTES = 1_000
FIT_WINDOW = 16  # acknowledged updates in a fit
MIN_SPREAD_BYTES = 1_000  # the sizes in a fit must differ this much (std) to tell slope from intercept
CAPACITY_RANGE = (0.05, 20.0)  # a fit is kept within these multiples of the first guess
MIN_ACK_TIMEOUT_S = 5.0


class ScenePacer:
    def __init__(self, share: float, capacity_bps: float, burst_bytes: int) -> None:
        """`capacity_bps`: the first guess (the configured satellite rate) until acks tell better."""
        self.share = share
        self.first_guess_bps = capacity_bps
        self.capacity_bps = capacity_bps
        self.rtt0_s = 0.0  # the link's round trip without our bytes, as fitted
        self.burst_bytes = burst_bytes
        self.tokens_bytes = float(burst_bytes)
        self.in_flight: dict[int, tuple[float, int]] = {}  # seq -> (sent at [s], bytes)
        self.lost = 0  # updates never acknowledged
        self.acked = 0
        self._samples: deque[tuple[int, float]] = deque(maxlen=FIT_WINDOW)  # (bytes, round trip [s])
        self._half = False  # the next update's size: full or half
        self._last_s: float | None = None

    def ack_timeout_s(self) -> float:
        return max(MIN_ACK_TIMEOUT_S, 4.0 * (self.rtt0_s + 8.0 * self.burst_bytes / self.capacity_bps))

    def tick(self, now_s: float) -> None:
        """Refill the bucket; give up on updates unacknowledged for too long."""
        if self._last_s is not None:
            dt = max(0.0, now_s - self._last_s)
            refill_bytes = self.share * self.capacity_bps / 8.0 * dt
            self.tokens_bytes = min(self.burst_bytes, self.tokens_bytes + refill_bytes)
        self._last_s = now_s
        timeout_s = self.ack_timeout_s()
        for seq, (sent_s, _) in list(self.in_flight.items()):
            if now_s - sent_s > timeout_s:
                del self.in_flight[seq]
                self.lost += 1

    def allows(self) -> bool:
        """Whether the next update may go now (it may take the bucket into debt): tokens left and
        no update of ours in flight."""
        return self.tokens_bytes > 0 and not self.in_flight

    def update_bytes(self) -> int:
        """The largest next update: `HEAD_OF_LINE_S` of the capacity within [MIN_UPDATE_BYTES,
        burst_bytes], every other one half of that (the probe that separates delay from rate)."""
        full = min(self.burst_bytes, max(MIN_UPDATE_BYTES, self.capacity_bps / 8.0 * HEAD_OF_LINE_S))
        return int(max(MIN_UPDATE_BYTES, full / 2) if self._half else full)

    def sent(self, now_s: float, nbytes: int, seq: int | None = None) -> None:
        """An update (with `seq`, to be acknowledged) or other bulk data of ours went out."""
        self.tokens_bytes -= nbytes
        if seq is not None:
            self.in_flight[seq] = (now_s, nbytes)
            self._half = not self._half

    def acknowledged(self, now_s: float, seq: int) -> None:
        """Shore's acknowledgement of update `seq` came back."""
        sent = self.in_flight.pop(seq, None)
        if sent is None:  # a late one, or a duplicate
            return
        self.acked += 1
        sent_s, nbytes = sent
        self._samples.append((nbytes, now_s - sent_s))
        self._fit()

    def _fit(self) -> None:
        if len(self._samples) < 4:
            return
        nbytes = np.array([b for b, _ in self._samples], dtype=float)
        rtt_s = np.array([r for _, r in self._samples])
        if nbytes.std() < MIN_SPREAD_BYTES:
            return
        slope_s_per_byte, intercept_s = np.polyfit(nbytes, rtt_s, 1)
        if slope_s_per_byte <= 0 or not math.isfinite(slope_s_per_byte):
            return
        lo, hi = (f * self.first_guess_bps for f in CAPACITY_RANGE)
        fitted_bps = float(np.clip(8.0 / slope_s_per_byte, lo, hi))
        self.capacity_bps += SMOOTHING * (fitted_bps - self.capacity_bps)
        self.rtt0_s = max(0.0, float(intercept_s))
