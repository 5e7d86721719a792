"""A station's Zenoh session, as the station sees it: publish and subscribe, nothing else.
Everything it receives is decoded and validated before the station sees it (a malformed
message is dropped, counted and logged once with its reason). What it publishes to a
neighbour leaves through that hop's egress: Zenoh directly, or, where the testbed routes it
(`route`), through the link emulator of that hop and direction. The station cannot see the
emulator: link control and statistics live on the testbed's side (`abyss.linkemu.control`)."""

from __future__ import annotations

import json
import logging
import math
import threading
from collections import Counter, defaultdict, deque
from collections.abc import Callable, Sequence
from typing import Any, Generic, NamedTuple, Protocol, TypeVar

import zenoh

from abyss.common.errors import BadMessage, BusError, ConfigError
from abyss.common.samples import Samples
from abyss.common.workers import Realtime
from abyss.interface import keys
from abyss.interface.messages import Message, Received, decode, encode
from abyss.interface.qos import publisher_qos, slow_link_tuning
from abyss.security import access
from abyss.security.certs import CertFiles
from abyss.timing.clock import WALL, Clock
from abyss.timing.rate import Rate

log = logging.getLogger(__name__)
TAKEN = b"taken"  # the answer to a message handed over by query and taken (Bus.take_key)


def zenoh_config(
    listen: Sequence[str] = (),
    connect: Sequence[str] = (),
    mode: str = "peer",
    *,
    tls: CertFiles | None = None,
    acl_station: str | None = None,
    slowest_rate_bps: float = math.inf,
) -> zenoh.Config:
    """Explicit endpoints, multicast scouting off: stations find each other only where told.
    With `tls` (its files checked here, at start), every endpoint is tls/ and both ends show
    certificates; with `acl_station`, that
    station's access control (`security.access`); `slowest_rate_bps` tunes the transmission queue."""
    access.check_endpoints([*listen, *connect], tls)
    config = zenoh.Config()
    config.insert_json5("mode", json.dumps(mode))
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("listen/endpoints", json.dumps(list(listen)))
    config.insert_json5("connect/endpoints", json.dumps(list(connect)))
    config.insert_json5(
        "transport/link/tx/queue/congestion_control", json.dumps(slow_link_tuning(slowest_rate_bps))
    )
    if tls is not None:
        config.insert_json5("transport/link/tls", json.dumps(access.tls_settings(tls.check())))
    if acl_station is not None:
        config.insert_json5("access_control", json.dumps(access.access_control(acl_station)))
    return config


def client_config(endpoint: str) -> zenoh.Config:
    """A tool's session with one station or `abyss up` (a tls/ endpoint takes the operator's
    certificate from $ABYSS_TLS_DIR)."""
    return zenoh_config(connect=[endpoint], mode="client", tls=access.tool_certificates(endpoint))


M = TypeVar("M", bound=Message)


def message_of(sample: zenoh.Sample, message: type[M]) -> M | None:
    """The `message` a sample carries, or None if its bytes do not decode to one: for tools that
    listen from outside the stations (which count and log what they drop)."""
    try:
        return decode(str(sample.key_expr), sample.payload.to_bytes(), message).message
    except BadMessage:
        return None


def checked_class(key: str, message: object, carried: type[Message] | None = None) -> type[Message]:
    """`message` if it is a message class (and `carried`, the class `keys.KEYS` gives the key, where
    it has one); ConfigError naming the key and both classes otherwise."""
    if not (isinstance(message, type) and issubclass(message, Message)):
        want = f"a message class ({carried.__name__})" if carried else "a message class"
        raise ConfigError(key, f"subscribed with {message!r}, not {want}")
    if carried is not None and message is not carried:
        raise ConfigError(key, f"carries {carried.TYPE}, not {message.TYPE}")
    return message


def open_session(config: zenoh.Config, what: str) -> zenoh.Session:
    try:
        return zenoh.open(config)
    except zenoh.ZError as exc:
        raise BusError(
            f"{what}: cannot open the Zenoh session ({exc}); check that the listen "
            "endpoints are free and of the form tcp/HOST:PORT"
        ) from None


class Inbox(Generic[M]):
    """Messages of type `M` received on one key, newest last; bounded."""

    def __init__(self, maxlen: int, clock: Clock = WALL) -> None:
        self._items: deque[Received[M]] = deque(maxlen=maxlen)
        self._lock = threading.Lock()
        self._clock = clock
        self._latest_received_s = -float("inf")  # this station's clock
        # a queue the station drains whose oldest messages newer ones pushed out before it came back:
        # the station fell behind (an inbox read only for its latest message sheds nothing)
        self.shed = 0
        self._drained = False

    def put(self, item: Received[M]) -> None:
        with self._lock:
            self.shed += self._drained and len(self._items) == self._items.maxlen
            self._items.append(item)
            self._latest_received_s = self._clock.now_s()

    def latest(self) -> Received[M] | None:
        with self._lock:
            return self._items[-1] if self._items else None

    def fresh(self, max_age_s: float) -> Received[M] | None:
        """The latest message if it arrived less than `max_age_s` ago by this station's
        clock (a sender's clock on another host may be off)."""
        with self._lock:
            if not self._items or self._clock.now_s() - self._latest_received_s > max_age_s:
                return None
            return self._items[-1]

    def drain(self) -> list[Received[M]]:
        with self._lock:
            self._drained = True
            items = list(self._items)
            self._items.clear()
            return items


Egress = Callable[[bytes, bool, str], bool]  # (payload, reliable, key) -> False if dropped on the way


class Outgoing(NamedTuple):
    """What publishing on one of a station's topics needs, worked out once."""

    spec: keys.KeySpec
    key: str
    hop: str
    reliable: bool

    @classmethod
    def of(cls, spec: keys.KeySpec, system: str) -> Outgoing:
        return cls(spec, spec.key(system), spec.hop, spec.reliability == "reliable")


class Tap(Protocol):
    """The testbed's recorder of what a station sends and receives (abyss.recording.store)."""

    def add(
        self,
        direction: str,
        key: str,
        payload: bytes,
        reason: str = "",
        envelope: tuple[int, float] | None = None,
    ) -> None: ...


class Bus:
    """Publish and subscribe for one station of one system. Counters are guarded: Zenoh's
    callback threads and the station's threads touch them at once. `clock`: the system's time
    (timing.clock), for the station's loops, ages and stamps."""

    def __init__(self, system: str, station: str, session: zenoh.Session, clock: Clock = WALL) -> None:
        self.system = keys.check_system_id(system)
        self.station = keys.check_station(station)
        self.session = session
        self.clock = clock
        self.stop = threading.Event()  # set when the station is asked to stop
        self.sent: Counter[str] = Counter()
        self.received: Counter[str] = Counter()
        self.rejected: Counter[str] = Counter()
        self.latency_s: defaultdict[str, Samples] = defaultdict(Samples)  # per received key: stamp to receipt
        self._reasons_logged: set[tuple[str, str]] = set()
        self._seq: Counter[str] = Counter()
        self._lock = threading.Lock()  # the counters, sequence numbers and reasons
        self._subscribers: list[Any] = []
        self._inboxes: list[tuple[str, Inbox[Any]]] = []
        self._data_keys: set[str] = set()
        self._shed: Counter[str] = Counter()  # what the station let go unprocessed, by key
        self._loops: dict[str, Rate] = {}
        self._egress: dict[str, Egress] = {}
        self.tap: Tap | None = None  # the testbed's recorder, where the run records
        self._outgoing = {s.topic: Outgoing.of(s, system) for s in keys.KEYS if s.station == station}
        self._publishers = {
            out.key: session.declare_publisher(out.key, **publisher_qos(out.spec, clock.mode == "lockstep"))
            for out in self._outgoing.values()
        }
        self._arrived: Counter[str] = Counter()  # what reached a neighbour's key's inbox, decoded or not
        self.on_arrival: Callable[[], None] = lambda: None
        self.lockstep: Any = None  # the station's periods, with --time lockstep (timing.lockstep.Lockstep)
        self.realtime = Realtime(0)  # the station's scheduling (the simulation's physics asks for more)
        self.about: dict[str, Any] = {}  # what the station says of itself (the simulation: its physics)

    def route(self, hop: str, egress: Egress) -> None:
        """Send what goes across `hop` through `egress` (the testbed's link emulator), which
        hands it back to `transmit` when the link delivers it."""
        self._egress[keys.check_hop(hop)] = egress

    # -- data plane ----------------------------------------------------------------------
    def publish(self, topic: str, message: Message) -> bool:
        """Send on `abyss/<system>/<this station>/<topic>` over its hop; False if the link
        dropped it (queue full, congestion control DROP)."""
        out = self._outgoing.get(topic) or Outgoing.of(keys.spec(self.station, topic), self.system)
        if type(message) is not out.spec.message_class:
            raise ConfigError(topic, f"carries {out.spec.message}, not {message.TYPE}")
        key = out.key
        with self._lock:  # stations publish from more than one thread
            seq, stamp_s = self._seq[key], self.clock.stamp_s()
            payload = encode(message, seq, stamp_s)
            self._seq[key] += 1
            self.sent[key] += 1
        if self.tap is not None:
            self.tap.add("sent", key, payload, envelope=(seq, stamp_s))
        egress = self._egress.get(out.hop)
        if egress is None:
            self.transmit(key, payload)
            return True
        return egress(payload, out.reliable, key)

    def transmit(self, key: str, payload: bytes) -> None:
        """Put encoded bytes on the wire now (the egress's delivery)."""
        self._publishers[key].put(payload)

    def subscribe(self, station: str, topic: str, message: type[M], maxlen: int = 64) -> Inbox[M]:
        """Receive what neighbour `station` publishes on `topic`: an `Inbox[message]`, `message` being
        the class the key carries as `keys.KEYS` says (ConfigError at once, naming the key and both
        classes, if it is another)."""
        spec = keys.spec(station, topic)
        if spec.to != self.station:
            raise ConfigError(f"{station}/{topic}", f"is sent to {spec.to}, not to {self.station}")
        key = spec.key(self.system)
        checked_class(key, message, spec.message_class)
        return self.subscribe_key(key, message, maxlen, data=True)

    def subscribe_key(self, key: str, message: type[M], maxlen: int = 64, data: bool = False) -> Inbox[M]:
        """Receive `message`s on any key, a control key included; validated and counted (`data`: a
        neighbour's key, whose arrivals are counted for lockstep whether they decode or not)."""
        checked_class(key, message)
        inbox: Inbox[M] = Inbox(maxlen, self.clock)
        self._inboxes.append((key, inbox))
        if data:
            with self._lock:
                self._data_keys.add(key)
        self._subscribers.append(
            self.session.declare_subscriber(
                key,
                lambda sample: self._on_sample(
                    str(sample.key_expr), message, sample.payload.to_bytes(), inbox, data
                ),
            )
        )
        return inbox

    def take_key(self, key: str, message: type[M], maxlen: int = 64) -> Inbox[M]:
        """Take the `message`s handed over by query on `key` (an operator's tool's commands): each
        validated and counted as a subscription's are, answered TAKEN (or with why it is refused),
        and put on `key` as taken, with the query's attachment (its sender), for whoever listens
        there. A tool thus knows that its command was taken, and never sends it again: resending
        it until it is answered is the taker's alone."""
        checked_class(key, message)
        inbox: Inbox[M] = Inbox(maxlen, self.clock)
        self._inboxes.append((key, inbox))

        def on_query(query: zenoh.Query) -> None:
            payload = query.payload.to_bytes() if query.payload is not None else b""
            reason = self._take(str(query.key_expr), message, payload, inbox)
            if reason:
                query.reply_err(reason)
                return
            query.reply(query.key_expr, TAKEN)
            attachment = query.attachment.to_bytes() if query.attachment is not None else None
            self.session.put(query.key_expr, payload, attachment=attachment)

        self._subscribers.append(self.session.declare_queryable(key, on_query))
        return inbox

    def data_keys(self) -> set[str]:
        """The neighbours' keys this station subscribes to."""
        with self._lock:
            return set(self._data_keys)

    def arrivals(self) -> Counter[str]:
        """What reached each neighbour's key's inbox so far, decoded or not."""
        with self._lock:
            return Counter(self._arrived)

    def _on_sample(
        self, key: str, expected: type[M], payload: bytes, inbox: Inbox[M], data: bool = False
    ) -> None:
        try:
            self._take(key, expected, payload, inbox)
        finally:
            if data:
                with self._lock:
                    self._arrived[key] += 1
                self.on_arrival()

    def _take(self, key: str, expected: type[M], payload: bytes, inbox: Inbox[M]) -> str:
        """Decode `payload` into `inbox`; why it was rejected ("" when it was taken)."""
        try:
            received = decode(key, payload, expected)
        except BadMessage as exc:
            self.reject(key, exc.reason)
            if self.tap is not None:
                self.tap.add("rejected", key, payload, exc.reason)
            return exc.reason
        if self.tap is not None:
            self.tap.add("received", key, payload, envelope=(received.seq, received.stamp_s))
        with self._lock:
            self.received[key] += 1
            self.latency_s[key].add(self.clock.stamp_s() - received.stamp_s)
        inbox.put(received)
        return ""

    def reject(self, key: str, reason: str) -> None:
        """Count a malformed input, and log its reason the first time it is seen."""
        with self._lock:
            self.rejected[key] += 1
            first = (key, reason) not in self._reasons_logged
            self._reasons_logged.add((key, reason))
        if first:
            log.warning("dropped a message on %s: %s", key, reason)

    # -- observation ---------------------------------------------------------------------
    def observe(self, key: str, message: Message) -> None:
        """Publish on an observation key (scoring, status), outside the links. In lockstep it
        blocks rather than drops, as every publisher there does: the records the supervisor writes
        from it (panel.csv) repeat row for row (a loaded machine dropped one of a run's)."""
        with self._lock:
            payload = encode(message, self._seq[key], self.clock.stamp_s())
            self._seq[key] += 1
        lockstep = self.clock.mode == "lockstep"
        self.session.put(
            key,
            payload,
            congestion_control=zenoh.CongestionControl.BLOCK if lockstep else zenoh.CongestionControl.DROP,
        )

    # -- life ----------------------------------------------------------------------------
    def loop(self, name: str, period_s: float, clock: Clock | None = None) -> Rate:
        """The rate of one of the station's periodic loops, on the station's clock (or `clock`);
        its deadlines met go in the status."""
        rate = self._loops[name] = Rate(period_s, self.stop, clock or self.clock, name)
        return rate

    def shed(self, key: str, count: int = 1) -> None:
        """The station let `count` messages of `key` go unprocessed, newer ones having come (load
        shedding: a station that falls behind drops the oldest, and says so)."""
        with self._lock:
            self._shed[key] += count

    def status(self) -> dict[str, Any]:
        """What this station sent, received, rejected and shed, its loops' deadlines met, the
        scheduler they run on and what it says of itself (`about`), for summary.json."""
        with self._lock:
            latency = {
                key: samples.percentiles("latency", 1e3, "ms") for key, samples in self.latency_s.items()
            }
            shed = self._shed + Counter({key: inbox.shed for key, inbox in self._inboxes})
            return {
                "sent": dict(self.sent),
                "received": dict(self.received),
                "rejected": dict(self.rejected),
                "latency_ms": latency,
                "shed": {key: n for key, n in shed.items() if n},
                "loops": {
                    name: {
                        "period_s": rate.period_s,
                        "ticks": rate.ticks,
                        "deadlines_met": round(rate.deadlines_met, 4),
                    }
                    for name, rate in self._loops.items()
                },
                "scheduler": self.realtime.scheduler,
                "about": dict(self.about),
            }

    def close(self) -> None:
        """Undeclare the subscribers, queryables and publishers (the session is the caller's)."""
        self.stop.set()
        for entity in [*self._subscribers, *self._publishers.values()]:
            entity.undeclare()
        self._subscribers.clear()
        self._publishers.clear()
