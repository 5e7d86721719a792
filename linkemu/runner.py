"""The link core on the system's clock (the wall clock, or simulated time: timing.clock): a
thread per link direction that hands each message to `deliver` at the time the emulated link
delivers it."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Container
from typing import Any

import numpy as np

from abyss.common.samples import Samples
from abyss.config.linkprofile import LinkProfile
from abyss.linkemu.link import Delivery, Link, Offer
from abyss.timing.clock import WALL, Clock, SimClock

log = logging.getLogger(__name__)


class LinkRunner:
    """Thread-safe wrapper of a `Link`. The ideal profile is a pass-through on the caller's
    thread, still counted; `passthrough=True` (the netem backend) forces that. Once `stopping`
    is set (the station is asked to stop), no sender waits for room any more: what it offers
    to a full queue is refused and counted (`refused_at_stop`). On a lockstep clock the runner has
    no thread: `deliver_due` is the period's delivery phase (timing.lockstep), nothing is passed
    through at once, and a sender that finds the queue full goes on in its loop's turn of the
    period the link has room (`LockstepClock.step_aside`)."""

    def __init__(
        self,
        name: str,
        profile: LinkProfile,
        deliver: Callable[[Any, bytes], None],
        rng: np.random.Generator,
        passthrough: bool = False,
        stopping: threading.Event | None = None,
        clock: Clock = WALL,
    ) -> None:
        self.name = name
        self.clock = clock
        self.driven = clock.mode == "lockstep"
        self.deliver = deliver
        self.passthrough = passthrough
        self.stopping = stopping or threading.Event()
        self.link = Link(profile, rng)
        self._direct = not self.driven and (passthrough or profile.is_ideal)  # follows the profile
        self.late_s = Samples()  # actual - scheduled delivery time
        self._cond = threading.Condition()
        self._closed = False
        self._thread = threading.Thread(target=self._loop, name=f"link-{name}", daemon=True)
        if isinstance(clock, SimClock) and not self.driven:
            clock.wake_on_tick(self._cond)  # a delivery due by a tick is made on it
        if not self.driven:
            self._thread.start()

    @property
    def profile(self) -> LinkProfile:
        return self.link.profile

    def in_flight(self, tags: Container[Any] | None = None) -> int:
        """Messages offered and neither delivered nor lost yet (of those tagged one of `tags`)."""
        with self._cond:
            return self.link.in_flight(tags)

    def send(self, payload: bytes, block: bool, tag: Any = None) -> bool:
        """Offer a message; False if the link dropped it (queue full with DROP).
        With `block`, wait for room in the queue as Zenoh's BLOCK does. On simulated time that
        wait is on the clock (`Clock.step_aside`): the link says when room next comes, and
        the sender's loop is done until then, so the simulation steps there and the queue
        drains; a wall-clock wait would hold simulated time for a queue that only simulated
        time drains."""
        while True:
            with self._cond:
                if self._direct and self.link.in_flight() == 0:
                    self.link.pass_through(len(payload))
                    break
                if self._closed or self.stopping.is_set():
                    self.link.counters["refused_at_stop"] += 1
                    return False
                now_s = self.clock.now_s()
                result = self.link.offer(now_s, payload, block, tag)
                if result is not Offer.FULL:
                    self._cond.notify_all()
                    return result is Offer.ACCEPTED
                if self.clock.mode == "real":
                    self._cond.wait(0.05)  # woken by a delivery that makes room
                    continue
                room_s = self.link.room_s(now_s, len(payload))
                self._cond.notify_all()  # what the link delivered by now, to the delivery thread
            if room_s is None or not self.clock.step_aside(max(room_s, now_s), self.stopping):
                with self._cond:  # no room to come, or no wait possible here: dropped, counted
                    if self.stopping.is_set():
                        self.link.counters["refused_at_stop"] += 1
                        return False
                    return self.link.offer(self.clock.now_s(), payload, False, tag) is Offer.ACCEPTED
        self.deliver(tag, payload)
        return True

    def reconfigure(self, profile: LinkProfile) -> None:
        with self._cond:
            self.link.reconfigure(profile)
            self._direct = not self.driven and (self.passthrough or profile.is_ideal)
            self._cond.notify_all()

    def snapshot(self) -> dict[str, float]:
        with self._cond:
            return {**self.link.snapshot(), **self.late_s.percentiles("late", 1e6, "us", (50, 99))}

    def close(self, drain_s: float = 0.0, join_s: float = 2.0) -> None:
        """Stop; with `drain_s`, first wait that long for messages still in flight. Whatever
        is still in flight then is counted as `undelivered_at_close`. The delivery thread is
        given `join_s` to finish a delivery under way (0: the caller joins it, `join`)."""
        deadline = time.monotonic() + drain_s
        with self._cond:
            while self.link.in_flight() and time.monotonic() < deadline:
                self._cond.wait(0.05)
            self.link.counters["undelivered_at_close"] += self.link.in_flight()
            self._closed = True
            self._cond.notify_all()
        self.join(join_s)

    def join(self, timeout_s: float) -> bool:
        """Wait up to `timeout_s` for the delivery thread to end; whether it did."""
        if self.driven:
            return True
        self._thread.join(timeout=max(0.0, timeout_s))
        return not self._thread.is_alive()

    def deliver_due(self, now_s: float) -> list[Any]:
        """Deliver what the link delivers by `now_s`, here, now (lockstep); the tags delivered."""
        with self._cond:
            ready = [] if self._closed else self.link.advance(now_s)
        for d in ready:
            try:
                self.deliver(d.tag, d.payload)
            except Exception:  # a failing subscriber must not stop the link
                log.exception("link %s: delivery failed", self.name)
        return [d.tag for d in ready]

    def _loop(self) -> None:
        while True:
            with self._cond:
                if self._closed:
                    return
                now_s = self.clock.now_s()
                ready: list[Delivery] = self.link.advance(now_s)
                for d in ready:
                    self.late_s.add(now_s - d.delivered_s)
                if ready:
                    self._cond.notify_all()  # room in the queue for blocked senders
                next_s = self.link.next_event_s()
                if not ready:
                    self._cond.wait(None if next_s is None else self.clock.wall_timeout_s(next_s - now_s))
            for d in ready:
                try:
                    self.deliver(d.tag, d.payload)
                except Exception:  # a failing subscriber must not stop the link
                    log.exception("link %s: delivery failed", self.name)
