"""Transport models: what the sender and receiver do about lost and corrupt packets."""

from abyss.linkemu.transport.tcp import Tcp
from abyss.linkemu.transport.udp import Udp

TRANSPORTS: dict[str, type[Tcp] | type[Udp]] = {"tcp": Tcp, "udp": Udp}

__all__ = ["TRANSPORTS", "Tcp", "Udp"]
