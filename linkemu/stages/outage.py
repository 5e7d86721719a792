from __future__ import annotations

from typing import Any

import numpy as np

from abyss.config.linkprofile import LinkProfile
from abyss.linkemu.stages.base import Packet, Stage


class Outage(Stage):
    """On-off outages (LinkProfile.outage_*), as mahimahi's mm-onoff: from the first packet the
    link is up, then down, and so on, on a timeline drawn from a generator seeded by the
    profile's seed alone (the same seed, the same outages, whatever the traffic); a packet that
    reaches it while the link is down is lost. A profile with other outage times starts a new
    timeline at the next packet."""

    drops = "outages"

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.shape: tuple[Any, ...] | None = None  # the outage fields the timeline was drawn for
        self.up = True
        self.until_s: float | None = None  # when the state ends [s]; None: from the next packet
        super().__init__(*args, **kwargs)

    def configure(self, profile: LinkProfile) -> None:
        super().configure(profile)
        shape = (profile.outage_up_s, profile.outage_down_s, profile.outage_times, profile.seed)
        if shape != self.shape:
            self.shape = shape
            self.timeline = np.random.default_rng([profile.seed, 0x0FF])
            self.up, self.until_s = True, None  # starts at the next packet, up

    def _duration_s(self, mean_s: float) -> float:
        return mean_s if self.profile.outage_times == "fixed" else float(self.timeline.exponential(mean_s))

    def process(self, packet: Packet) -> list[Packet]:
        p = self.profile
        if p.outage_down_s <= 0.0:
            return [packet]
        if self.until_s is None:
            self.until_s = packet.t_s + self._duration_s(p.outage_up_s)
        while packet.t_s >= self.until_s:
            self.up = not self.up
            self.until_s += self._duration_s(p.outage_up_s if self.up else p.outage_down_s)
        return [packet] if self.up else []
