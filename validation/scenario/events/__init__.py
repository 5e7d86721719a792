"""Scenario events, one kind per file: a frozen dataclass on `base.Event` whose typed fields are
its `[[events]]` table's fields. `EVENTS` registers each by the name its table's `action` gives;
adding a kind is one file and one line here."""

from __future__ import annotations

import dataclasses

from abyss.validation.scenario.events.base import Context, Event, Running
from abyss.validation.scenario.events.fault import Fault
from abyss.validation.scenario.events.kill import Kill
from abyss.validation.scenario.events.link import Link

EVENTS: dict[str, type[Event]] = {
    "link": Link,
    "fault": Fault,
    "kill": Kill,
}


def action_of(event: Event) -> str:
    """The name `event`'s kind is registered under (its table's `action`)."""
    return next(name for name, kind in EVENTS.items() if type(event) is kind)


def fields_of(kind: type[Event]) -> tuple[str, ...]:
    """The fields a kind's table takes besides `action`, the common ones first."""
    return tuple(f.name for f in dataclasses.fields(kind))


__all__ = ["EVENTS", "Context", "Event", "Fault", "Kill", "Link", "Running", "action_of", "fields_of"]
