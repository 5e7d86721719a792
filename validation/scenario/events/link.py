from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Annotated

from abyss.common.reading import OneOf
from abyss.config.linkprofile import load_profiles
from abyss.interface import keys
from abyss.interface.messages import LinkControl, encode
from abyss.linkemu.control import query_links
from abyss.validation.scenario.events.base import Context, Event


@dataclass(frozen=True, kw_only=True)
class Link(Event):
    """A hop's link emulation switched to a named profile (config/profiles.toml), both ends."""

    hop: Annotated[str, OneOf(keys.HOPS)]
    profile: Annotated[str, OneOf(load_profiles)]

    def describe(self) -> str:
        return f"link {self.hop} -> {self.profile}"

    def apply(self, ctx: Context) -> str:
        control = LinkControl(self.profile, {})
        ctx.session.put(keys.link_key(ctx.system_id, self.hop), encode(control, 0, time.time()))
        return self.describe()

    def settled(self, ctx: Context) -> str:
        ctx.wait(
            f"both ends of {self.hop} on {self.profile}",
            lambda: (
                [s.profile for s in query_links(ctx.session, ctx.system_id, self.hop, 1.0)]
                == [self.profile] * 2
            ),
        )
        return ""
