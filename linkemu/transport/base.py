"""What a transport model may use of the link that owns it (linkemu/link.py's `Link`, its "for
transports" part): the link's profile, draws and counters, its stage pipeline, and the calls that
put packets on the wire and deliver what arrives. A transport is written against this, so the
link and its transports do not import each other."""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:
    import numpy as np

    from abyss.config.linkprofile import LinkProfile
    from abyss.linkemu.stages import Packet, Pipeline


class Wire(Protocol):
    """The link, as its transport sees it."""

    profile: LinkProfile
    rng: np.random.Generator
    counters: dict[str, int]
    pipeline: Pipeline

    @property
    def payload_per_packet(self) -> int: ...

    def schedule(self, t_s: float, action: Callable[[float], None]) -> None: ...

    def transmit(self, t_s: float, packet: Packet) -> list[Packet]: ...

    def checksum_ok(self, packet: Packet) -> bool: ...

    def receive_part(self, t_s: float, packet: Packet) -> None: ...

    def finish_message(self, message_id: int) -> None: ...

    def next_timed_s(self) -> float | None: ...
