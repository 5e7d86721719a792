"""Transport models: what the sender and receiver do about lost and corrupt packets."""

from linkemu.transport.tcp import Tcp
from linkemu.transport.udp import Udp

TRANSPORTS = {"tcp": Tcp, "udp": Udp}

__all__ = ["TRANSPORTS", "Tcp", "Udp"]
