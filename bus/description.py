"""The running system's description on the bus (interface.system_description): served to a query
by the shell of each station the testbed hosts, fetched by the operator's tools from whichever
station answers first (they all run one configuration)."""

from __future__ import annotations

import zenoh

from abyss.common.errors import BadInput, BusError
from abyss.interface import keys
from abyss.interface.system_description import SystemDescription, description_of


def serve(session: zenoh.Session, system: str, station: str, payload: bytes) -> zenoh.Queryable:
    """Answer every query on `station`'s description key with `payload` (keep the queryable)."""
    key = keys.description_key(system, station)

    def answer(query: zenoh.Query) -> None:
        query.reply(key, payload)

    return session.declare_queryable(key, answer)


def fetch(session: zenoh.Session, system: str, timeout_s: float = 5.0) -> SystemDescription:
    """The description of the system `system` that `session` reaches; BusError where no station
    of it answers within `timeout_s` (no such system runs there), BadInput where they answer only
    with a malformed description."""
    wrong: BadInput | None = None
    for reply in session.get(keys.description_key(system, "*"), timeout=timeout_s):
        if reply.ok is None:
            continue
        try:
            return description_of(reply.ok.payload.to_bytes())
        except BadInput as exc:
            wrong = exc
    if wrong is not None:
        raise BadInput(f"system {system!r} described itself wrongly: {wrong.reason}")
    raise BusError(f"no station of system {system!r} described the running system in {timeout_s:g} s")
