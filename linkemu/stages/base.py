from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from abyss.config.linkprofile import LinkProfile


@dataclass
class Packet:
    """One packet of a message on the wire."""

    seq: int  # transport sequence number on this link direction
    message: int  # id of the message it belongs to
    index: int  # position in its message
    data: bytes  # the slice of the message it carries
    crc: int  # checksum of `data` taken at the sender
    size_bytes: int  # on the wire, headers included
    t_s: float  # when it reaches the current stage [s]
    last: bool  # the last part of its message
    corrupt: bool = False
    transmission: int = 0  # 0 for the first, 1.. for retransmissions
    acked: bool = False
    head: bytes = b""  # bytes before `data` that no stage touches (a TUN packet's IP header)

    def copy(self) -> Packet:
        return dataclasses.replace(self)


class Stage:
    """A pipeline stage. `drops` names the statistic a packet it swallows counts under."""

    drops = ""

    def __init__(self, profile: LinkProfile, rng: np.random.Generator) -> None:
        self.rng = rng
        self.configure(profile)

    def configure(self, profile: LinkProfile) -> None:
        """Apply a new profile; packets already through the stage keep their times."""
        self.profile = profile

    def process(self, packet: Packet) -> list[Packet]:
        raise NotImplementedError
