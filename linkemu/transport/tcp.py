from __future__ import annotations

import dataclasses
import functools
import heapq
import itertools
import math
import zlib
from collections import deque
from collections.abc import Callable
from typing import TYPE_CHECKING

from abyss.linkemu.stages import Packet

if TYPE_CHECKING:
    from abyss.linkemu.transport.base import Wire

INITIAL_CWND = 10.0  # packets (Linux's initial window)
INITIAL_RTO_S = 1.0  # RFC 6298
MIN_RTO_VAR_S = 0.2  # Linux: RTO = SRTT + max(4 RTTVAR, 200 ms)
MAX_RTO_S = 60.0
DUPACK_THRESHOLD = 3  # packets sent later and acknowledged that make a packet lost at once
DELAYED_ACK_S = 0.2  # a probe waits this much more for a lone packet's (delayed) acknowledgement


class Tcp:
    """A TCP connection carrying every message of the link direction, as Zenoh's TCP link
    carries every key between two peers: Linux's TCP as it ships (SACK, RACK-TLP, PRR), with
    Reno's window; bench/tcp_model.py holds it against the kernel's through the TUN shaper.

    The messages are one byte stream, cut into segments of up to a packet's payload when the
    window lets them go: a message waiting for the window shares its segment with the next.
    The receiver delivers in order and acknowledges every segment, cumulatively and
    selectively (the sender knows which arrived); acknowledgements take the profile's delay,
    jitter (in order), loss and corruption back. A corrupt segment fails the receiver's
    checksum and is not acknowledged. The sender:

    - takes a packet for lost when a packet sent after it has been acknowledged and a
      reordering window (a quarter of the least round trip) has passed, or at once when three
      have (RACK with SACK's duplicate threshold), and retransmits every such packet;
    - halves the window once per window of data (recovery), spreading its sending over
      the recovery round (proportional rate reduction) rather than pausing;
    - sends a tail loss probe two round trips after its last packet (or when the timer would
      fire, if sooner) when nothing is acknowledged, so that a lost tail is recovered by the
      above, not by a timeout;
    - keeps one retransmission timer (RFC 6298), restarted whenever the oldest packet is
      acknowledged: when it fires, every packet in flight is taken for lost, the window
      falls to one packet and the timer backs off, until a round trip is measured again
      (timestamps: from a retransmission's acknowledgement too);
    - counts its window in whole packets, grows it only while it limits the sending, and
      after an idle spell of more than a timeout starts again from at most the initial window.
    """

    def __init__(self, link: Wire) -> None:
        self.link = link
        self.ack_rng = link.rng.spawn(1)[0]  # the data direction's draws stay those of a UDP link
        self.cwnd = INITIAL_CWND
        self.ssthresh = math.inf
        self.state = "open"  # or "recovery" (window halved) or "loss" (after a timeout)
        self.srtt_s: float | None = None
        self.rttvar_s = 0.0
        self.min_rtt_s = math.inf
        self.rto_s = INITIAL_RTO_S
        self.unsent: deque[Packet] = deque()
        self.unacked: dict[int, Packet] = {}  # every packet sent and not acknowledged, in order
        self.in_flight: dict[int, Packet] = {}  # of those, not taken for lost; in send order
        self.retransmit: list[int] = []  # heap of sequence numbers taken for lost
        self.sent_s: dict[int, float] = {}  # each unacknowledged packet's last transmission
        self.unsent_offset = 0  # bytes of unsent[0] already in a segment
        self.pieces: dict[int, list[tuple[Packet, int, int]]] = {}  # what each segment carries
        self._segment_numbers = itertools.count()
        self.later_acked: dict[int, int] = {}  # packets sent after it and acknowledged
        self.highest_sent = -1
        self.recovery_seq = -1  # the state ends when every packet up to this one is acknowledged
        self.prior_cwnd = self.prr_delivered = self.prr_out = 0.0  # proportional rate reduction
        self.rack_sent_s, self.rack_rtt_s = -math.inf, 0.0  # the latest-sent packet acknowledged
        self.last_sent_s = 0.0
        self.rto_from_s = 0.0  # the retransmission timer runs from here
        self.probing = False  # a tail loss probe is out
        self._timer = 0  # generation of the armed retransmission or probe timer
        self._reorder_timer = 0
        self.rcv_next = 0
        self.rcv_buffer: dict[int, tuple[Packet, list[tuple[Packet, int, int]]]] = {}  # out of order
        self.rcv_part = bytearray()  # the message part whose first bytes have arrived
        self.rtt_sum_s, self.rtt_samples = 0.0, 0  # for the mean round trip
        self.first_rto_sum_s, self.first_timeouts = 0.0, 0  # RTO when a timeout starts a backoff
        self._backing_off = False
        self._last_ack_s = 0.0

    def has_room(self, now_s: float, packets: int) -> bool:
        queued = len(self.unsent) + len(self.unacked)  # parts not sent, segments not acknowledged
        return queued + packets <= self.link.profile.queue_limit_packets

    def room_s(self, now_s: float, packets: int) -> float | None:
        """Room comes with an acknowledgement or a timer, each an event of the link's."""
        return now_s if self.has_room(now_s, packets) else self.link.next_timed_s()

    def send(self, now_s: float, packets: list[Packet]) -> None:
        if not self.unacked and now_s - self.last_sent_s > self.rto_s:
            self._restart_after_idle(now_s - self.last_sent_s)
        self.unsent.extend(packets)
        if self._pump(now_s):
            self._arm_timer(now_s)

    def gauges(self) -> dict[str, float]:
        return {
            "cwnd_packets": self.cwnd,
            "srtt_ms": (self.srtt_s or 0.0) * 1e3,
            "rto_ms": self.rto_s * 1e3,
            "rtt_mean_ms": self.rtt_sum_s / max(1, self.rtt_samples) * 1e3,
            "first_rto_mean_ms": self.first_rto_sum_s / max(1, self.first_timeouts) * 1e3,
        }

    # -- sender: sending -----------------------------------------------------------------
    def _pump(self, t_s: float) -> int:
        """Send what the window allows; how many packets."""
        sent = 0
        while len(self.in_flight) + 1 <= self.cwnd and self._send_next(t_s):
            sent += 1
        return sent

    def _send_next(self, t_s: float) -> bool:
        """Send the lowest packet taken for lost, else the next new one; False when none."""
        while self.retransmit:
            packet = self.unacked.get(heapq.heappop(self.retransmit))
            if packet is not None:  # not acknowledged while waiting for its retransmission
                self._transmit(t_s, packet)
                return True
        if not self.unsent:
            return False
        packet = self._next_segment()
        if not self.unacked:
            self.rto_from_s = t_s
        self.unacked[packet.seq] = packet
        self._transmit(t_s, packet)
        return True

    def _next_segment(self) -> Packet:
        """Up to a packet's worth of the unsent bytes: the messages are one byte stream, so
        small ones that waited for the window leave together, as in a TCP stream."""
        pieces: list[tuple[Packet, int, int]] = []  # (message part, offset, length)
        room = self.link.payload_per_packet
        while self.unsent and (room > 0 or not self.unsent[0].data):
            part = self.unsent[0]
            length = min(room, len(part.data) - self.unsent_offset)
            pieces.append((part, self.unsent_offset, length))
            room -= length
            self.unsent_offset += length
            if self.unsent_offset == len(part.data):
                self.unsent.popleft()
                self.unsent_offset = 0
        first = pieces[0][0]
        data = b"".join(part.data[offset : offset + length] for part, offset, length in pieces)
        seq = next(self._segment_numbers)
        self.pieces[seq] = pieces
        return Packet(
            seq=seq,
            message=first.message,
            index=first.index,
            data=data,
            crc=zlib.crc32(data),
            size_bytes=first.size_bytes - len(first.data) + len(data),
            t_s=0.0,
            last=False,
        )

    def _transmit(self, t_s: float, packet: Packet) -> None:
        if packet.seq <= self.highest_sent:
            packet.transmission += 1
            self.link.counters["retransmissions"] += 1
            if packet.seq == next(iter(self.unacked)):
                self.rto_from_s = t_s
        if self.state == "recovery":
            self.prr_out += 1
        self.sent_s[packet.seq] = self.last_sent_s = t_s
        self.later_acked[packet.seq] = 0
        self.in_flight.pop(packet.seq, None)
        self.in_flight[packet.seq] = packet  # the latest sent last
        self.highest_sent = max(self.highest_sent, packet.seq)
        for copy in self.link.transmit(t_s, packet.copy()):
            self.link.schedule(copy.t_s, functools.partial(self._arrive, packet=copy))

    def _restart_after_idle(self, idle_s: float) -> None:
        """Linux's tcp_cwnd_restart: halve the window per timeout spent idle, down to the
        initial window."""
        restart = min(INITIAL_CWND, self.cwnd)
        self.ssthresh = max(self.ssthresh, 0.75 * self.cwnd)
        while (idle_s := idle_s - self.rto_s) > 0 and self.cwnd > restart:
            self.cwnd /= 2.0
        self.cwnd = max(self.cwnd, restart)

    # -- sender: timers ------------------------------------------------------------------
    def _arm_timer(self, t_s: float) -> None:
        """The retransmission timer, or the probe timer when a tail loss probe would come first."""
        self._timer += 1
        if not self.unacked:
            return
        due_s = max(t_s, self.rto_from_s + self.rto_s)
        if self.state == "open" and not self.probing and self.srtt_s is not None:
            pto_s = 2.0 * self.srtt_s + (DELAYED_ACK_S if len(self.unacked) == 1 else 0.0)
            self._schedule_timer(min(t_s + pto_s, due_s), self._probe)  # Linux: no later than the RTO
        else:
            self._schedule_timer(due_s, self._timeout)

    def _schedule_timer(self, t_s: float, action: Callable[[float], None]) -> None:
        """`action` at `t_s` unless the timer is armed again before."""
        generation = self._timer
        self.link.schedule(t_s, lambda t: action(t) if generation == self._timer else None)

    def _probe(self, t_s: float) -> None:
        """Tail loss probe: one new packet, whatever the window, else the last one again."""
        self.probing = True
        if not self._send_next(t_s) and self.unacked:
            self._transmit(t_s, next(reversed(self.unacked.values())))
        self._arm_timer(t_s)

    def _timeout(self, t_s: float) -> None:
        self.link.counters["timeouts"] += 1
        if not self._backing_off:
            self.first_rto_sum_s += self.rto_s
            self.first_timeouts += 1
            self.ssthresh = self._halved_window()
            self._backing_off = True
        self.state, self.recovery_seq, self.cwnd = "loss", self.highest_sent, 1.0
        self.rto_s = min(self.rto_s * 2.0, MAX_RTO_S)
        for lost in list(self.in_flight.values()):
            self._take_for_lost(lost)
        self._pump(t_s)
        self._arm_timer(t_s)

    # -- sender: acknowledgements --------------------------------------------------------
    def _ack(self, t_s: float, seq: int, transmission: int, cumulative: int, block: tuple[int, int]) -> None:
        """An acknowledgement of segment `seq` (its `transmission`), of every segment below
        `cumulative` and of those in `block` (SACK: the received ones around `seq`, beyond a
        gap), so that what a lost acknowledgement did not say, the next one does."""
        low, high = block  # `seq` is in it, or below `cumulative`
        delivered = list(itertools.takewhile(lambda s: s < cumulative, self.unacked))
        delivered += [s for s in range(max(low, cumulative), high + 1) if s in self.unacked]
        if not delivered:
            return  # a duplicate acknowledgement
        oldest = next(iter(self.unacked))
        in_flight = len(self.in_flight)
        for each in delivered:
            self._delivered(t_s, each, transmission if each == seq else None)
        if not self.unacked or next(iter(self.unacked)) != oldest:  # the oldest is acknowledged
            self.rto_from_s = t_s
            self.probing = False
        self._detect_losses(t_s)
        if self.state == "recovery":
            self._reduce_window(delivered=float(len(delivered)))
        elif in_flight + 1 > self.cwnd or (self.cwnd < self.ssthresh and 2 * in_flight > self.cwnd):
            for _ in delivered:  # the window limits the sending: it grows
                self.cwnd += 1.0 if self.cwnd < self.ssthresh else 1.0 / self.cwnd
        if self.state != "open" and (not self.unacked or next(iter(self.unacked)) > self.recovery_seq):
            if self.state == "recovery":
                self.cwnd = self.ssthresh
            self.state = "open"
        self._pump(t_s)
        self._arm_timer(t_s)

    def _delivered(self, t_s: float, seq: int, transmission: int | None) -> None:
        """Segment `seq` reached the receiver: `transmission` of it, when the acknowledgement says."""
        packet = self.unacked.pop(seq)
        sent_s = self.sent_s.pop(seq)
        # the acknowledgement echoes the transmission it answers (TCP timestamps, on in Linux by
        # default: RFC 7323's RTTM): a retransmission's round trip is measured too, and the first
        # after an outage ends the timer's backoff, as Linux's icsk_backoff ends
        if transmission == packet.transmission:
            self._rtt_sample(t_s - sent_s)
        # RACK needs the send time of what arrived: known unless it was sent more than once
        known = transmission == packet.transmission if transmission is not None else packet.transmission == 0
        if known and sent_s > self.rack_sent_s:
            self.rack_sent_s, self.rack_rtt_s = sent_s, t_s - sent_s
        if seq in self.in_flight:
            for earlier in self.in_flight:  # sent before `seq`, in send order
                if earlier == seq:
                    break
                self.later_acked[earlier] += 1
            del self.in_flight[seq]
        del self.later_acked[seq], self.pieces[seq]

    def _detect_losses(self, t_s: float) -> None:
        """RACK: a packet sent before the latest-sent one acknowledged is lost once a reordering
        window has passed since that one's round trip would have brought its acknowledgement
        (at once after three later acknowledgements, or in recovery)."""
        quick = self.state != "open"
        reorder_s = 0.0 if quick else min(self.min_rtt_s / 4.0, self.srtt_s or 0.0)
        lost, wake_s = [], math.inf
        for seq, packet in self.in_flight.items():
            if self.sent_s[seq] >= self.rack_sent_s:
                break
            due_s = self.sent_s[seq] + self.rack_rtt_s
            if self.later_acked[seq] < DUPACK_THRESHOLD:
                due_s += reorder_s
            if due_s <= t_s:
                lost.append(packet)
            else:
                wake_s = min(wake_s, due_s)
        if any(packet.seq > self.recovery_seq for packet in lost):  # once per window of data
            self.state, self.recovery_seq = "recovery", self.highest_sent
            self.ssthresh = self._halved_window()
            self.prior_cwnd, self.prr_delivered, self.prr_out = max(self.cwnd, 1.0), 0.0, 0.0
        for packet in lost:
            self._take_for_lost(packet)
        self._reorder_timer += 1
        if math.isfinite(wake_s):
            generation = self._reorder_timer
            self.link.schedule(
                wake_s, lambda t: self._reorder_timeout(t) if generation == self._reorder_timer else None
            )

    def _reorder_timeout(self, t_s: float) -> None:
        self._detect_losses(t_s)
        if self.state == "recovery":
            self._reduce_window(delivered=0.0)
        self._pump(t_s)
        self._arm_timer(t_s)

    def _reduce_window(self, delivered: float) -> None:
        """Proportional rate reduction (RFC 6937, as Linux): in recovery, send about
        ssthresh / cwnd packets per packet delivered, and no fewer than one to begin."""
        self.prr_delivered += delivered
        in_flight = float(len(self.in_flight))
        if in_flight > self.ssthresh:
            allowed = math.ceil(self.prr_delivered * self.ssthresh / self.prior_cwnd) - self.prr_out
        else:
            allowed = min(self.ssthresh - in_flight, max(self.prr_delivered - self.prr_out, delivered) + 1.0)
        self.cwnd = in_flight + max(allowed, 0.0 if self.prr_out else 1.0)

    def _halved_window(self) -> float:
        """Reno's slow-start threshold after a loss: half the window, in whole packets."""
        return max(float(math.floor(self.cwnd) // 2), 2.0)

    def _take_for_lost(self, packet: Packet) -> None:
        del self.in_flight[packet.seq]
        heapq.heappush(self.retransmit, packet.seq)

    def _rtt_sample(self, rtt_s: float) -> None:
        self.rtt_sum_s += rtt_s
        self.rtt_samples += 1
        self.min_rtt_s = min(self.min_rtt_s, rtt_s)
        self._backing_off = False
        if self.srtt_s is None:
            self.srtt_s, self.rttvar_s = rtt_s, rtt_s / 2.0
        else:
            self.rttvar_s = 0.75 * self.rttvar_s + 0.25 * abs(self.srtt_s - rtt_s)
            self.srtt_s = 0.875 * self.srtt_s + 0.125 * rtt_s
        self.rto_s = min(self.srtt_s + max(4.0 * self.rttvar_s, MIN_RTO_VAR_S), MAX_RTO_S)

    # -- receiver ------------------------------------------------------------------------
    def _deliver(self, t_s: float, segment: Packet, pieces: list[tuple[Packet, int, int]]) -> None:
        """Hand the application each message part the segment completes, with the bytes that
        arrived (a flipped bit included)."""
        position = 0
        for part, offset, length in pieces:
            self.rcv_part += segment.data[position : position + length]
            position += length
            if offset + length == len(part.data):
                data, self.rcv_part = bytes(self.rcv_part), bytearray()
                self.link.receive_part(t_s, dataclasses.replace(part, data=data, corrupt=data != part.data))
                if part.last:
                    self.link.finish_message(part.message)

    def _arrive(self, t_s: float, packet: Packet) -> None:
        if not self.link.checksum_ok(packet):
            return  # dropped by the receiver: no acknowledgement
        if packet.seq >= self.rcv_next and packet.seq not in self.rcv_buffer:
            self.rcv_buffer[packet.seq] = (packet, self.pieces[packet.seq])
        while self.rcv_next in self.rcv_buffer:
            self._deliver(t_s, *self.rcv_buffer.pop(self.rcv_next))
            self.rcv_next += 1
        # the acknowledgement crosses the reverse path: the profile's delay, jitter (in order),
        # loss and corruption
        p = self.link.profile
        if p.mean_loss + p.corrupt > 0.0 and self.ack_rng.random() < p.mean_loss + p.corrupt:
            return
        ack_s = t_s + max(0.0, p.delay_s + p.jitter_s * float(self.ack_rng.standard_normal()))
        ack_s = self._last_ack_s = max(ack_s, self._last_ack_s)
        seq, transmission, cumulative = packet.seq, packet.transmission, self.rcv_next
        block = self._block(seq)
        self.link.schedule(ack_s, lambda t: self._ack(t, seq, transmission, cumulative, block))

    def _block(self, seq: int) -> tuple[int, int]:
        """The received segments around `seq` that wait for a gap before them to fill."""
        low = high = seq
        while low - 1 in self.rcv_buffer:
            low -= 1
        while high + 1 in self.rcv_buffer:
            high += 1
        return low, high
