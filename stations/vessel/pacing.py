"""How fast scene updates may go to shore: a token bucket filled at a share of the satellite
link's capacity as measured, so that telemetry on the same link is never starved.

Capacity is measured the way a sender can: bytes the link delivered per second while one of
our updates was in flight the whole time (an idle link says nothing about its capacity, and
telemetry in flight alone says only how little telemetry there is: counting it made the
estimate sink to telemetry's rate and starve the scene). The first guess is the
emulated profile's rate, else `satellite_capacity_bps`. One scene update at most is in flight
at once (counted among the link's messages in flight by key, so that telemetry in flight does
not hold the scene back), so telemetry never queues behind more than one update."""

from __future__ import annotations

import math

SMOOTHING = 0.3  # weight of a new capacity sample
HEAD_OF_LINE_S = 0.25  # an update takes at most this long of the link: telemetry's wait behind it [s]
MIN_UPDATE_BYTES = 1_000


class ScenePacer:
    def __init__(self, share: float, capacity_bps: float, burst_bytes: int) -> None:
        self.share = share
        self.capacity_bps = capacity_bps
        self.burst_bytes = burst_bytes
        self.tokens_bytes = float(burst_bytes)
        self._last_s: float | None = None
        self._last_delivered = 0.0
        self._busy = False

    def observe(self, now_s: float, bytes_delivered: float, in_flight: float) -> None:
        """Feed the link's delivered bytes and how many of our updates are in flight; refills
        the bucket and updates the capacity estimate."""
        if self._last_s is not None:
            dt = now_s - self._last_s
            if self._busy and in_flight > 0 and dt > 0:
                sample_bps = 8.0 * (bytes_delivered - self._last_delivered) / dt
                if sample_bps > 0:
                    self.capacity_bps += SMOOTHING * (sample_bps - self.capacity_bps)
            self.tokens_bytes = min(
                self.burst_bytes, self.tokens_bytes + self.share * self.capacity_bps / 8.0 * dt
            )
        self._last_s, self._last_delivered, self._busy = now_s, bytes_delivered, in_flight > 0

    def allows(self, updates_in_flight: int) -> bool:
        """Whether the next update may go now (it may take the bucket into debt): tokens left and
        no update of ours still in flight."""
        return self.tokens_bytes > 0 and updates_in_flight == 0

    def update_bytes(self) -> int:
        """The largest update now: `HEAD_OF_LINE_S` of the measured capacity, within
        [MIN_UPDATE_BYTES, burst_bytes] (16 kB at 1 Mbit/s, 8 kB in a 256 kbit/s storm)."""
        return int(min(self.burst_bytes, max(MIN_UPDATE_BYTES, self.capacity_bps / 8.0 * HEAD_OF_LINE_S)))

    def sent(self, nbytes: int) -> None:
        self.tokens_bytes -= nbytes

    @staticmethod
    def first_guess(profile_rate_bps: float, configured_bps: float) -> float:
        return profile_rate_bps if math.isfinite(profile_rate_bps) else configured_bps
