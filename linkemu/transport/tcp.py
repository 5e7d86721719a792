from __future__ import annotations

import functools
import heapq
import math
from collections import deque
from typing import TYPE_CHECKING

from abyss.linkemu.stages import Packet

if TYPE_CHECKING:
    from abyss.linkemu.link import Link

INITIAL_CWND = 10.0  # packets (Linux's initial window)
INITIAL_RTO_S = 1.0  # RFC 6298
MIN_RTO_VAR_S = 0.2  # Linux: RTO = SRTT + max(4 RTTVAR, 200 ms)
MAX_RTO_S = 60.0
DUPACK_THRESHOLD = 3


class Tcp:
    """A TCP connection carrying every message of the link direction, as Zenoh's TCP link
    carries every key between two peers.

    Reno congestion control with SACK-style loss detection: a packet is taken for lost
    when three packets sent after it are acknowledged (fast retransmit: the window halves,
    once per window of data) or when its retransmission timer fires (the window falls to
    one packet and the timer backs off). The receiver delivers in order and acknowledges
    every packet; acknowledgements take the profile's delay and jitter back, in order. A corrupt packet
    fails the receiver's checksum, is not acknowledged, and is retransmitted as if lost.
    """

    def __init__(self, link: Link) -> None:
        self.link = link
        self.cwnd = INITIAL_CWND
        self.ssthresh = math.inf
        self.srtt_s: float | None = None
        self.rttvar_s = 0.0
        self.rto_s = INITIAL_RTO_S
        self.unsent: deque[Packet] = deque()
        self.unacked: dict[int, Packet] = {}  # every packet sent and not acknowledged
        self.in_flight: dict[int, Packet] = {}  # of those, not taken for lost; in send order
        self.retransmit: list[int] = []  # heap of sequence numbers taken for lost
        self.sent_s: dict[int, float] = {}
        self.dupacks: dict[int, int] = {}
        self.recovery_seq = -1  # no second window cut for losses among packets sent before
        self.highest_sent = -1
        self.rcv_next = 0
        self.rcv_buffer: dict[int, Packet] = {}
        self.rtt_sum_s, self.rtt_samples = 0.0, 0  # for the mean round trip
        self.first_rto_sum_s, self.first_timeouts = 0.0, 0  # RTO when a timeout starts a backoff
        self._backing_off = False
        self._last_ack_s = 0.0

    def has_room(self, now_s: float, packets: int) -> bool:
        queued = len(self.unsent) + len(self.unacked)
        return queued + packets <= self.link.profile.queue_limit_packets

    def send(self, now_s: float, packets: list[Packet]) -> None:
        self.unsent.extend(packets)
        self._pump(now_s)

    def gauges(self) -> dict[str, float]:
        return {"cwnd_packets": self.cwnd, "srtt_ms": (self.srtt_s or 0.0) * 1e3,
                "rto_ms": self.rto_s * 1e3,
                "rtt_mean_ms": self.rtt_sum_s / max(1, self.rtt_samples) * 1e3,
                "first_rto_mean_ms": self.first_rto_sum_s / max(1, self.first_timeouts) * 1e3}

    # -- sender --------------------------------------------------------------------------
    def _pump(self, t_s: float) -> None:
        while len(self.in_flight) < self.cwnd:
            if self.retransmit:
                packet = self.unacked.get(heapq.heappop(self.retransmit))
                if packet is None:  # acknowledged while waiting for its retransmission
                    continue
            elif self.unsent:
                packet = self.unsent.popleft()
                self.unacked[packet.seq] = packet
            else:
                return
            self._transmit(t_s, packet)

    def _transmit(self, t_s: float, packet: Packet) -> None:
        self.sent_s[packet.seq] = t_s
        self.dupacks[packet.seq] = 0
        self.in_flight[packet.seq] = packet
        self.highest_sent = max(self.highest_sent, packet.seq)
        for copy in self.link.transmit(t_s, packet.copy()):
            self.link.schedule(copy.t_s, functools.partial(self._arrive, packet=copy))
        transmission = packet.transmission
        self.link.schedule(t_s + self.rto_s, lambda t: self._timeout(t, packet.seq, transmission))

    def _take_for_lost(self, packet: Packet) -> None:
        del self.in_flight[packet.seq]
        packet.transmission += 1
        self.link.counters["retransmissions"] += 1
        heapq.heappush(self.retransmit, packet.seq)

    def _cut_window(self, timeout: bool) -> None:
        """Halve the window (fast retransmit) or fall to one packet (timeout)."""
        self.ssthresh = max(len(self.in_flight) / 2.0, 2.0)
        self.cwnd = 1.0 if timeout else self.ssthresh
        self.recovery_seq = self.highest_sent

    def _ack(self, t_s: float, seq: int, transmission: int) -> None:
        packet = self.unacked.pop(seq, None)
        if packet is None:
            return  # a duplicate acknowledgement
        if packet.transmission == 0 == transmission:  # Karn: no sample from retransmissions
            self._rtt_sample(t_s - self.sent_s[seq])
        if seq in self.in_flight:
            for earlier in list(self.in_flight.values()):  # sent before `seq`, still unacked
                if earlier.seq == seq:
                    break
                if earlier.seq < seq:
                    self.dupacks[earlier.seq] += 1
                    # Reno: one fast retransmit per window; a second loss in the same
                    # window waits for its retransmission timer
                    if self.dupacks[earlier.seq] == DUPACK_THRESHOLD and earlier.seq > self.recovery_seq:
                        self._cut_window(timeout=False)
                        self._take_for_lost(earlier)
            del self.in_flight[seq]
        del self.sent_s[seq], self.dupacks[seq]
        self.cwnd += 1.0 if self.cwnd < self.ssthresh else 1.0 / self.cwnd
        self.cwnd = min(self.cwnd, float(self.link.profile.queue_limit_packets))
        self._pump(t_s)

    def _timeout(self, t_s: float, seq: int, transmission: int) -> None:
        packet = self.in_flight.get(seq)
        if packet is None or packet.transmission != transmission:
            return
        self.link.counters["timeouts"] += 1
        if not self._backing_off:
            self.first_rto_sum_s += self.rto_s
            self.first_timeouts += 1
            self._backing_off = True
        self._cut_window(timeout=True)
        self.rto_s = min(self.rto_s * 2.0, MAX_RTO_S)
        for lost in list(self.in_flight.values()):
            self._take_for_lost(lost)
        self._pump(t_s)

    def _rtt_sample(self, rtt_s: float) -> None:
        self.rtt_sum_s += rtt_s
        self.rtt_samples += 1
        self._backing_off = False
        if self.srtt_s is None:
            self.srtt_s, self.rttvar_s = rtt_s, rtt_s / 2.0
        else:
            self.rttvar_s = 0.75 * self.rttvar_s + 0.25 * abs(self.srtt_s - rtt_s)
            self.srtt_s = 0.875 * self.srtt_s + 0.125 * rtt_s
        self.rto_s = min(self.srtt_s + max(4.0 * self.rttvar_s, MIN_RTO_VAR_S), MAX_RTO_S)

    # -- receiver ------------------------------------------------------------------------
    def _arrive(self, t_s: float, packet: Packet) -> None:
        if not self.link.checksum_ok(packet):
            return  # dropped by the receiver: no acknowledgement
        if packet.seq >= self.rcv_next:
            self.rcv_buffer.setdefault(packet.seq, packet)
        while self.rcv_next in self.rcv_buffer:
            part = self.rcv_buffer.pop(self.rcv_next)
            self.link.receive_part(t_s, part)
            if part.last:
                self.link.finish_message(part.message)
            self.rcv_next += 1
        # the acknowledgement crosses the reverse path: same mean delay and jitter, in order
        p = self.link.profile
        ack_s = t_s + max(0.0, p.delay_s + p.jitter_s * float(self.link.rng.standard_normal()))
        ack_s = self._last_ack_s = max(ack_s, self._last_ack_s)
        self.link.schedule(ack_s, lambda t: self._ack(t, packet.seq, packet.transmission))
