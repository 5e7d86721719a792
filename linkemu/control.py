"""The testbed's side of one station's links: the emulator of each hop at the station's
egress, and its control plane over Zenoh. A profile is set on `abyss/<system>/link/<hop>`
(put) and read with its statistics there (get); the statistics go out on
`abyss/<system>/<station>/linkstats/<hop>` every second. With a shaper (`--link tun`: the
TUN forwarder, `--link netem`: tc/netem; `auto`: netem where the kernel has it, else tun, else
emulated) the emulators pass through and each hop's profile shapes this host's packets
towards the neighbour instead. The station itself never sees any of this (`abyss.bus.session`)."""

from __future__ import annotations

import functools
import logging
import sys
import threading
import time
import typing
from collections import Counter
from collections.abc import Callable
from typing import Literal, Protocol

import numpy as np
import zenoh

from abyss.common.errors import AbyssError, BadMessage, LinkError
from abyss.config.linkprofile import LinkProfile
from abyss.config.linkprofile import profile as named_profile
from abyss.interface import keys
from abyss.interface.messages import LinkControl, LinkStats, decode, encode
from abyss.linkemu.netem import NetemShaper
from abyss.linkemu.route import route_towards
from abyss.linkemu.runner import LinkRunner
from abyss.linkemu.tun import TunShaper, tun_name
from abyss.timing.clock import WALL, Clock

log = logging.getLogger(__name__)
LINKSTATS_PERIOD_S = 1.0
LinkMode = Literal["emulated", "tun", "netem", "auto"]
LINK_MODES: tuple[LinkMode, ...] = typing.get_args(LinkMode)


def link_mode_of(text: str) -> LinkMode:
    """`text` (as the user typed it) as a link mode; LinkError with the allowed ones if it is none."""
    for mode in LINK_MODES:
        if text == mode:
            return mode
    raise LinkError(f"link mode {text!r}: allowed {', '.join(LINK_MODES)}")


AUTO_ORDER = ("netem", "tun")  # then emulated
MESSAGE_COUNTERS = (
    "messages_",
    "bytes_offered",
    "bytes_delivered",
    "undelivered_at_close",
    "refused_at_stop",
)


class Shaper(Protocol):
    """A hop's profile applied to this host's real packets (tun, netem)."""

    def reconfigure(self, profile: LinkProfile) -> None: ...
    def snapshot(self) -> dict[str, float]: ...
    def close(self) -> None: ...


def link_rng(seed: int, station: str, hop: str) -> np.random.Generator:
    """One random stream per station and hop, from the system's seed."""
    return np.random.default_rng([seed, keys.STATIONS.index(station), list(keys.HOPS).index(hop)])


class StationLinks:
    """Each hop of `station`: its emulator (`runners[hop].send` is the station's egress), the
    link control keys, the statistics, a shaper of real packets where asked."""

    def __init__(
        self,
        session: zenoh.Session,
        system: str,
        station: str,
        profiles: dict[str, LinkProfile],
        deliver: Callable[[str, bytes], None],
        *,
        seed: int = 0,
        link_mode: str = "emulated",
        peers: dict[str, str] | None = None,
        stopping: threading.Event | None = None,
        clock: Clock = WALL,
    ) -> None:
        """`deliver(key, payload)` puts a message on the wire when its link delivers it;
        `peers[hop]`: the neighbour whose route a shaper takes (a name or an address; default:
        the neighbour's station name); `stopping`: set when the station is asked to stop, from
        when on no send waits for room on a link; `clock`: the time the emulators run on."""
        mode = link_mode_of(link_mode)
        if clock.mode != "real" and mode != "emulated":
            raise LinkError(
                f"link mode {link_mode}: shapes real packets on the wall clock, which --time "
                f"{clock.mode} cannot run faster; use --link emulated, or --time real"
            )
        self.session = session
        self.system = system
        self.station = station
        self.stop = threading.Event()
        self.received: Counter[str] = Counter()  # link control messages taken
        self.rejected: Counter[str] = Counter()
        self.runners: dict[str, LinkRunner] = {}
        self.delivered: Counter[str] = Counter()  # per key, in lockstep (deliver_due)
        self._entities: list[zenoh.Subscriber | zenoh.Queryable] = []
        self.mode, self.shapers = self._shapers(mode, profiles, peers or {}, seed)
        for hop, neighbour in keys.hops_of(station).items():
            self.runners[hop] = LinkRunner(
                f"{hop}:{station}->{neighbour}",
                profiles.get(hop, LinkProfile()),
                deliver,
                link_rng(seed, station, hop),
                passthrough=hop in self.shapers,
                stopping=stopping,
                clock=clock,
            )
            self._entities.append(
                session.declare_subscriber(
                    keys.link_key(system, hop), functools.partial(self._on_control_sample, hop)
                )
            )
            self._entities.append(
                session.declare_queryable(keys.link_key(system, hop), functools.partial(self._on_query, hop))
            )
        self._stats_thread = threading.Thread(target=self._publish_stats, name="linkstats", daemon=True)
        self._stats_thread.start()

    def deliver_due(self, now_s: float) -> Counter[str]:
        """Lockstep's delivery phase: each hop's messages due by `now_s` delivered; the messages
        delivered on each key so far."""
        for runner in self.runners.values():
            self.delivered.update(runner.deliver_due(now_s))
        return Counter(self.delivered)

    def egress(self, hop: str) -> Callable[[bytes, bool, str], bool]:
        """What the station's bus sends `hop`'s messages through."""
        runner = self.runners[hop]
        return lambda payload, reliable, key: runner.send(payload, reliable, tag=key)

    def _shapers(
        self, link_mode: LinkMode, profiles: dict[str, LinkProfile], peers: dict[str, str], seed: int
    ) -> tuple[str, dict[str, Shaper]]:
        """The link mode in force and its shapers; `auto` says which it took and why."""
        if link_mode == "emulated":
            return link_mode, {}
        tried: list[str] = []
        try:
            routes = {
                hop: route_towards(peers.get(hop, neighbour))
                for hop, neighbour in keys.hops_of(self.station).items()
            }
        except LinkError as exc:
            if link_mode != "auto":
                raise
            routes, tried = {}, [str(exc)]
        for mode in (AUTO_ORDER if link_mode == "auto" else (link_mode,)) if routes else ():
            shapers: dict[str, Shaper] = {}
            try:
                for hop, route in routes.items():
                    name = f"{hop}:{self.station}->{keys.hops_of(self.station)[hop]}"
                    profile = profiles.get(hop, LinkProfile())
                    shapers[hop] = (
                        NetemShaper(name, route.device, profile)
                        if mode == "netem"
                        else TunShaper(name, route, profile, link_rng(seed, self.station, hop), tun_name(hop))
                    )
            except LinkError as exc:
                for shaper in shapers.values():
                    shaper.close()
                if link_mode != "auto":
                    raise
                tried.append(f"{mode}: {exc}")
                continue
            if tried:
                log.info("link mode auto: %s (%s)", mode, "; ".join(tried))
            return mode, shapers
        log.warning("link mode auto: emulated (%s)", "; ".join(tried))
        return "emulated", {}

    def _on_control_sample(self, hop: str, sample: zenoh.Sample) -> None:
        self._on_control(hop, sample.payload.to_bytes())

    def _on_control(self, hop: str, payload: bytes) -> None:
        key = keys.link_key(self.system, hop)
        runner = self.runners[hop]
        try:
            control = decode(key, payload, LinkControl).message
            base = named_profile(control.profile) if control.profile else runner.profile
            runner.reconfigure(base.with_fields(control.overrides))
            if hop in self.shapers:
                self.shapers[hop].reconfigure(runner.profile)
        except (AbyssError, BadMessage) as exc:
            self.rejected[key] += 1
            log.warning("link control on %s refused: %s", key, exc)
            return
        self.received[key] += 1
        log.info("link %s now %s %s", runner.name, runner.profile.name, runner.profile.fields())

    def stats(self, hop: str) -> LinkStats:
        runner = self.runners[hop]
        stats = runner.snapshot()
        if hop in self.shapers:  # the runner only counts messages; the shaper has the packets
            stats = {k: v for k, v in stats.items() if k.startswith(MESSAGE_COUNTERS)}
            stats.update(self.shapers[hop].snapshot())
        return LinkStats(
            hop=hop,
            direction=runner.name.split(":", 1)[1],
            profile=runner.profile.name,
            fields=runner.profile.fields(),
            stats=stats,
        )

    def _on_query(self, hop: str, query: zenoh.Query) -> None:
        query.reply(keys.link_key(self.system, hop), encode(self.stats(hop), 0, time.time()))

    def _publish_stats(self) -> None:
        seq = 0
        while not self.stop.wait(LINKSTATS_PERIOD_S):
            for hop in self.runners:
                key = keys.linkstats_key(self.system, self.station, hop)
                self.session.put(key, encode(self.stats(hop), seq, time.time()))
            seq += 1

    def status(self) -> dict[str, dict[str, object]]:
        """Each hop's direction, profile and statistics, for summary.json."""
        links: dict[str, dict[str, object]] = {}
        for hop in self.runners:
            stats = self.stats(hop)
            links[hop] = {
                "direction": stats.direction,
                "profile": stats.profile,
                "mode": self.mode,
                **stats.stats,
            }
        return links

    def close(self, drain_s: float = 0.0, join_s: float = 1.0) -> None:
        """Stop the emulators (what is still in flight after `drain_s` is counted, not
        delivered; a delivery under way is given `join_s` for all links together), remove
        the shapers, undeclare the control keys."""
        self.stop.set()
        for runner in self.runners.values():
            runner.close(drain_s, join_s=0.0)
        deadline = time.monotonic() + join_s
        for runner in self.runners.values():
            if not runner.join(deadline - time.monotonic()):
                log.warning("link %s: a delivery still under way at close, let go", runner.name)
        for shaper in self.shapers.values():
            shaper.close()
        self._stats_thread.join(timeout=max(0.0, deadline - time.monotonic()))
        for entity in self._entities:
            entity.undeclare()


def query_links(
    session: zenoh.Session, system: str, hop: str | None, timeout_s: float = 3.0
) -> list[LinkStats]:
    """Each station's statistics of `hop` (every hop: None), as its links answer on the control
    key, in the hops' order; a bad reply is ignored, said on stderr."""
    selector = keys.link_key(system, hop) if hop else keys.key(system, "link", "*")
    found = []
    for reply in session.get(selector, consolidation=zenoh.ConsolidationMode.NONE, timeout=timeout_s):
        if reply.ok is None:
            continue
        try:
            message = decode(str(reply.ok.key_expr), reply.ok.payload.to_bytes(), LinkStats).message
        except BadMessage as exc:
            print(f"abyss: ignoring a bad reply: {exc}", file=sys.stderr)
            continue
        found.append(message)
    return sorted(found, key=lambda s: (list(keys.HOPS).index(s.hop), s.direction))
