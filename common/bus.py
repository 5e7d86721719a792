"""A station's Zenoh session. Everything a station publishes to a neighbour goes through
the link emulator of that hop and direction at this station's egress (one shared queue
per direction); everything it receives is decoded and validated before the station sees
it. Control (link profiles) and observation (link statistics, liveliness) keys bypass
the emulator: they belong to the testbed, not to the system under test."""

from __future__ import annotations

import json
import logging
import math
import threading
import time
from collections import Counter, deque
from collections.abc import Sequence
from typing import Any

import numpy as np
import zenoh
from abyss.common import keys, security
from abyss.common.certs import CertFiles
from abyss.common.errors import AbyssError, BadMessage, BusError, ConfigError, LinkError
from abyss.common.messages import LinkControl, LinkStats, Message, Received, decode, encode
from abyss.common.samples import Samples
from abyss.linkemu.netem import interface_towards, netem_args, run_tc, tc_command
from abyss.linkemu.profile import LinkProfile
from abyss.linkemu.profile import profile as named_profile
from abyss.linkemu.runner import LinkRunner

log = logging.getLogger(__name__)
LINKSTATS_PERIOD_S = 1.0


ZENOH_PRIORITY = {"control": zenoh.Priority.INTERACTIVE_HIGH, "telemetry": zenoh.Priority.DATA_HIGH,
                  "bulk": zenoh.Priority.DATA_LOW}
LARGE_MESSAGE_BYTES = 256 * 1024  # the largest message a slow hop must carry without dropping it
ZENOH_DEFAULT_WAIT_BEFORE_DROP_S = 0.001
ZENOH_DEFAULT_WAIT_BEFORE_CLOSE_S = 5.0


def slow_link_tuning(rate_bps: float) -> dict[str, Any]:
    """`transport/link/tx/queue/congestion_control` for a link of `rate_bps`: Zenoh drops a DROP
    message whose batches find the queue full for 1 ms, and closes the link when a BLOCK message
    waits 5 s; a 256 kB message needs 2.1 s at 1 Mbit/s, so both waits grow with the time the
    link takes to carry one large message."""
    serialise_s = 0.0 if math.isinf(rate_bps) else LARGE_MESSAGE_BYTES * 8.0 / rate_bps
    drop_us = round(1e6 * min(max(ZENOH_DEFAULT_WAIT_BEFORE_DROP_S, serialise_s), 5.0))
    close_us = round(1e6 * max(ZENOH_DEFAULT_WAIT_BEFORE_CLOSE_S, 10.0 * serialise_s))
    return {"drop": {"wait_before_drop": drop_us, "max_wait_before_drop_fragments": max(drop_us, 50_000)},
            "block": {"wait_before_close": close_us}}


def zenoh_config(listen: Sequence[str] = (), connect: Sequence[str] = (), mode: str = "peer", *,
                 tls: CertFiles | None = None, acl_station: str | None = None,
                 slowest_rate_bps: float = math.inf) -> zenoh.Config:
    """Explicit endpoints, multicast scouting off: stations find each other only where told.
    With `tls` (its files checked here, at start), every endpoint is tls/ and both ends show
    certificates; with `acl_station`, that
    station's access control (`common.security`); `slowest_rate_bps` tunes the transmission queue."""
    security.check_endpoints([*listen, *connect], tls)
    config = zenoh.Config()
    config.insert_json5("mode", json.dumps(mode))
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("listen/endpoints", json.dumps(list(listen)))
    config.insert_json5("connect/endpoints", json.dumps(list(connect)))
    config.insert_json5("transport/link/tx/queue/congestion_control",
                        json.dumps(slow_link_tuning(slowest_rate_bps)))
    if tls is not None:
        config.insert_json5("transport/link/tls", json.dumps(security.tls_settings(tls.check())))
    if acl_station is not None:
        config.insert_json5("access_control", json.dumps(security.access_control(acl_station)))
    return config


def client_config(endpoint: str) -> zenoh.Config:
    """A tool's session with one station or `abyss up` (a tls/ endpoint takes the operator's
    certificate from $ABYSS_TLS_DIR)."""
    return zenoh_config(connect=[endpoint], mode="client", tls=security.tool_certificates(endpoint))


def message_of(sample: zenoh.Sample, message: str) -> Message | None:
    """The `message` a sample carries, or None if its bytes do not decode to one: for tools that
    listen from outside the stations (which count and log what they drop)."""
    try:
        return decode(str(sample.key_expr), sample.payload.to_bytes(), message).message
    except BadMessage:
        return None


def open_session(config: zenoh.Config, what: str) -> zenoh.Session:
    try:
        return zenoh.open(config)
    except zenoh.ZError as exc:
        raise BusError(f"{what}: cannot open the Zenoh session ({exc}); check that the listen "
                       "endpoints are free and of the form tcp/HOST:PORT") from None


class Inbox:
    """Messages received on one key, newest last; bounded."""

    def __init__(self, maxlen: int) -> None:
        self._items: deque[Received] = deque(maxlen=maxlen)
        self._lock = threading.Lock()
        self._latest_received_s = -float("inf")  # this station's monotonic clock

    def put(self, item: Received) -> None:
        with self._lock:
            self._items.append(item)
            self._latest_received_s = time.monotonic()

    def latest(self) -> Received | None:
        with self._lock:
            return self._items[-1] if self._items else None

    def fresh(self, max_age_s: float) -> Received | None:
        """The latest message if it arrived less than `max_age_s` ago by this station's
        clock (a sender's clock on another host may be off)."""
        with self._lock:
            if not self._items or time.monotonic() - self._latest_received_s > max_age_s:
                return None
            return self._items[-1]

    def drain(self) -> list[Received]:
        with self._lock:
            items = list(self._items)
            self._items.clear()
            return items


class Bus:
    """Publish and subscribe for one station of one system."""

    def __init__(self, system: str, station: str, profiles: dict[str, LinkProfile], *,
                 listen: Sequence[str] = (), connect: Sequence[str] = (), seed: int = 0,
                 link_mode: str = "emulated", mode: str = "peer", tls: CertFiles | None = None,
                 peers: dict[str, str] | None = None) -> None:
        """`mode`: Zenoh's (peer under `abyss up`; router where stations on separate hosts
        form the network themselves, so that a tool at one end reaches all of them); `tls`: this
        station's certificates, which turn on TLS and access control; `link_mode` netem: the
        in-process links pass through and each hop's profile is applied with tc/netem to the
        interface towards the neighbour at `peers[hop]` (default: the neighbour's name)."""
        self.system = keys.check_system_id(system)
        self.station = keys.check_station(station)
        self.stop = threading.Event()
        self.sent: Counter[str] = Counter()
        self.received: Counter[str] = Counter()
        self.rejected: Counter[str] = Counter()
        self.latency_s: dict[str, Samples] = {}  # per received key: sender stamp to receipt
        self._reasons_logged: set[tuple[str, str]] = set()
        self._seq: Counter[str] = Counter()
        self._publish_lock = threading.Lock()
        self._closing: list[Any] = []
        hops = keys.hops_of(station)
        slowest_bps = min(profiles.get(hop, LinkProfile()).rate_bps for hop in hops)
        config = zenoh_config(listen, connect, mode, tls=tls, acl_station=station if tls else None,
                              slowest_rate_bps=slowest_bps)  # bad endpoints or certificates fail here
        self.refusals = security.refusal_log() if tls is not None else None
        self.session = open_session(config, f"station {station}")
        self._publishers = {
            s.key(system): self.session.declare_publisher(
                s.key(system),
                congestion_control=zenoh.CongestionControl.BLOCK
                if s.reliability == "reliable" else zenoh.CongestionControl.DROP,
                priority=ZENOH_PRIORITY[s.priority], express=s.priority == "control",
            )
            for s in keys.KEYS if s.station == station
        }
        self.links: dict[str, LinkRunner] = {}
        self.netem_devices: dict[str, str] = {}  # hop -> interface shaped by tc/netem
        for hop, neighbour in hops.items():
            rng = np.random.default_rng([seed, keys.STATIONS.index(station), list(keys.HOPS).index(hop)])
            self.links[hop] = LinkRunner(f"{hop}:{station}->{neighbour}", profiles.get(hop, LinkProfile()),
                                         self._put, rng, passthrough=link_mode == "netem")
            if link_mode == "netem":
                self.netem_devices[hop] = interface_towards((peers or {}).get(hop, neighbour))
                self._apply_netem(hop)
            self._closing.append(self.session.declare_subscriber(
                keys.link_key(system, hop), lambda s, h=hop: self._on_link_control(h, s)))
            self._closing.append(self.session.declare_queryable(
                keys.link_key(system, hop), lambda q, h=hop: self._on_link_query(h, q)))
        self._token = self.session.liveliness().declare_token(keys.alive_key(system, station))
        self._stats_thread = threading.Thread(target=self._publish_linkstats, daemon=True)
        self._stats_thread.start()

    def _apply_netem(self, hop: str) -> None:
        device, runner = self.netem_devices[hop], self.links[hop]
        run_tc(tc_command(device, runner.profile))
        log.info("netem on %s (%s): %s", device, runner.name, " ".join(netem_args(runner.profile)))

    # -- data plane ----------------------------------------------------------------------
    def publish(self, topic: str, message: Message) -> bool:
        """Send on `abyss/<system>/<this station>/<topic>` over its hop; False if the link
        dropped it (queue full, congestion control DROP)."""
        spec = keys.spec(self.station, topic)
        if spec.message != message.TYPE:
            raise ConfigError(topic, f"carries {spec.message}, not {message.TYPE}")
        key = spec.key(self.system)
        with self._publish_lock:  # stations publish from more than one thread
            payload = encode(message, self._seq[key], time.time())
            self._seq[key] += 1
            self.sent[key] += 1
        return self.links[spec.hop].send(payload, spec.reliability == "reliable", tag=key)

    def subscribe(self, station: str, topic: str, maxlen: int = 64) -> Inbox:
        """Receive what neighbour `station` publishes on `topic`."""
        spec = keys.spec(station, topic)
        if spec.to != self.station:
            raise ConfigError(f"{station}/{topic}", f"is sent to {spec.to}, not to {self.station}")
        return self.subscribe_key(spec.key(self.system), spec.message, maxlen)

    def subscribe_key(self, key: str, message: str, maxlen: int = 64) -> Inbox:
        """Receive `message`s on any key, a control key included; validated and counted."""
        inbox = Inbox(maxlen)
        self._closing.append(self.session.declare_subscriber(
            key, lambda sample: self._on_sample(key, message, sample, inbox)))
        return inbox

    def _put(self, key: str, payload: bytes) -> None:
        self._publishers[key].put(payload)

    def _on_sample(self, key: str, expected: str, sample: zenoh.Sample, inbox: Inbox) -> None:
        try:
            received = decode(key, sample.payload.to_bytes(), expected)
        except BadMessage as exc:
            self.reject(key, exc.reason)
            return
        self.received[key] += 1
        self.latency_s.setdefault(key, Samples()).add(time.time() - received.stamp_s)
        inbox.put(received)

    def reject(self, key: str, reason: str) -> None:
        """Count a malformed input, and log its reason the first time it is seen."""
        self.rejected[key] += 1
        if (key, reason) not in self._reasons_logged:
            self._reasons_logged.add((key, reason))
            log.warning("dropped a message on %s: %s", key, reason)

    # -- control and observation ---------------------------------------------------------
    def observe(self, key: str, message: Message) -> None:
        """Publish on an observation key, outside the emulated links."""
        with self._publish_lock:
            payload = encode(message, self._seq[key], time.time())
            self._seq[key] += 1
        self.session.put(key, payload)

    def _on_link_control(self, hop: str, sample: zenoh.Sample) -> None:
        key = keys.link_key(self.system, hop)
        try:
            control = decode(key, sample.payload.to_bytes(), "LinkControl").message
            assert isinstance(control, LinkControl)
            runner = self.links[hop]
            base = named_profile(control.profile) if control.profile else runner.profile
            runner.reconfigure(base.with_fields(control.overrides))
            if hop in self.netem_devices:
                self._apply_netem(hop)
        except AbyssError as exc:
            self.reject(key, str(exc))
            return
        self.received[key] += 1
        log.info("link %s now %s %s", runner.name, runner.profile.name, runner.profile.fields())

    def link_down(self, hop: str) -> bool:
        """Whether this station's emulator of `hop` is set to lose everything (an outage)."""
        runner = self.links.get(hop)
        return runner is not None and not runner.passthrough and runner.profile.loss >= 1.0

    def link_stats(self, hop: str) -> LinkStats:
        runner = self.links[hop]
        return LinkStats(hop=hop, direction=runner.name.split(":", 1)[1], profile=runner.profile.name,
                         fields=runner.profile.fields(), stats=runner.snapshot())

    def _on_link_query(self, hop: str, query: zenoh.Query) -> None:
        query.reply(keys.link_key(self.system, hop), encode(self.link_stats(hop), 0, time.time()))

    def _publish_linkstats(self) -> None:
        while not self.stop.wait(LINKSTATS_PERIOD_S):
            for hop in self.links:
                self.observe(keys.linkstats_key(self.system, self.station, hop), self.link_stats(hop))

    # -- life ----------------------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        """What this station did, for summary.json."""
        links = {}
        for hop in self.links:
            stats = self.link_stats(hop)
            links[hop] = {"direction": stats.direction, "profile": stats.profile, **stats.stats}
        latency = {key: samples.percentiles("latency", 1e3, "ms") for key, samples in self.latency_s.items()}
        refused = dict(self.refusals.refused) if self.refusals else {}
        return {"sent": dict(self.sent), "received": dict(self.received), "rejected": dict(self.rejected),
                "refused": refused, "latency_ms": latency, "links": links}

    def close(self, drain_s: float = 0.5) -> None:
        self.stop.set()
        for runner in self.links.values():
            runner.close(drain_s)
        for hop, device in self.netem_devices.items():
            try:
                run_tc(tc_command(device, None))
            except LinkError as exc:
                log.warning("could not remove netem from %s (%s): %s", device, hop, exc)
        self._stats_thread.join(timeout=2.0)
        self._token.undeclare()
        for entity in self._closing:
            entity.undeclare()
        for publisher in self._publishers.values():
            publisher.undeclare()
        self.session.close()
