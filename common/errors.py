"""The one exception tree: every error a user can meet says what is wrong and how to fix it."""

from __future__ import annotations


class AbyssError(Exception):
    """Root of every error abyss raises on purpose."""


class ConfigError(AbyssError):
    """A configuration file, field or command-line value is invalid."""

    def __init__(self, field: str, reason: str, source: str = "") -> None:
        where = f"{source}: " if source else ""
        super().__init__(f"{where}{field}: {reason}")
        self.field = field
        self.reason = reason
        self.source = source


class UnknownProfile(ConfigError):
    def __init__(self, name: str, available: list[str]) -> None:
        super().__init__("profile", f"unknown link profile {name!r}; available: {', '.join(available)}")
        self.name = name
        self.available = available


class BadInput(AbyssError):
    """Input from outside the process (bytes from the network, a message's fields, an image) that
    is not valid. Decoders raise it and the station shells catch it, drop the input and count it
    as rejected with `reason`; nothing else is caught as "rejected", so a defect in abyss itself
    (a numpy shape error in a decoder, say) still surfaces as the bug it is."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


class BadMessage(BadInput):
    """Bytes from the network on `key` that do not decode to a valid message."""

    def __init__(self, key: str, reason: str) -> None:
        AbyssError.__init__(self, f"{key}: {reason}")
        self.key = key
        self.reason = reason


class LinkError(AbyssError):
    """The link emulator or the netem backend cannot do what was asked."""


class BusError(AbyssError):
    """The Zenoh session cannot be opened or used."""
