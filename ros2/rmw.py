"""rmw_zenoh's wire contract (ROS 2 Jazzy and later; rmw_zenoh's docs/design.md and
rmw_zenoh_cpp/src/detail, release 0.2.10): what a ROS 2 node with
RMW_IMPLEMENTATION=rmw_zenoh_cpp puts on Zenoh and expects there, spoken without ROS.

- A topic's data key: `<domain>/<topic without its leading slash>/<pkg>::msg::dds_::<Name>_/<RIHS01 hash>`.
- A payload: CDR with its 4-byte encapsulation header (`00 01 00 00`, little-endian).
- An attachment on every sample (a subscriber drops a sample without one): the sequence number
  (int64, from 1), the source timestamp (int64, ns since the epoch), and the publisher's GID (a
  length byte 16, then 16 bytes): zenoh-ext's serialisation of (int64, int64, uint8[16]), 33 bytes.
- Liveliness tokens, one per node and per endpoint, that `ros2 node|topic list|info` read:
  `@ros2_lv/<domain>/<zid>/<node id>/<entity id>/<NN|MP|MS>/<enclave>/<namespace>/<node>
  [/<topic>/<type>/<hash>/<qos>]`, every `/` inside a field written `%`.
- A GID: XXH3-128 of the endpoint's token, its two 64-bit halves little-endian.
- QoS in a token: `rel:dur:hist,depth:deadline s,ns:lifespan s,ns:liveliness,lease s,ns`, each
  field empty where it is rmw_zenoh's default (reliable, volatile, keep-last 42, infinite, automatic).
- QoS on Zenoh: reliable or best-effort, congestion control DROP (BLOCK for reliable keep-all);
  transient local: an advanced publisher whose cache holds the last `depth` samples, and which
  late subscribers query.
"""

from __future__ import annotations

import itertools
import logging
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import xxhash
import zenoh
import zenoh.ext
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability

from abyss.common.errors import BadInput
from abyss.ros2.msgs import TYPESTORE

log = logging.getLogger(__name__)

LIVELINESS_PREFIX = "@ros2_lv"
NODE, PUBLISHER, SUBSCRIPTION = "NN", "MP", "MS"
DEFAULT_ENCLAVE = "/"
# rmw_zenoh's own default QoS (qos.cpp), the fields a token leaves empty
DEFAULT_DEPTH = 42
_DEFAULTS = (QosReliability.RELIABLE, QosDurability.VOLATILE, QosHistory.KEEP_LAST, QosLiveliness.AUTOMATIC)
ATTACHMENT = struct.Struct("<qqB")  # sequence number, source timestamp [ns], the GID's length (16)
GID_BYTES = 16
CDR_HEADERS = (b"\x00\x01\x00\x00", b"\x00\x00\x00\x00")  # CDR little- and big-endian


def dds_type(type_name: str) -> str:
    """The type as rmw_zenoh names it: geometry_msgs/msg/Twist -> geometry_msgs::msg::dds_::Twist_."""
    package, kind, name = type_name.split("/")
    return f"{package}::{kind}::dds_::{name}_"


def type_hash(type_name: str) -> str:
    """REP 2016's RIHS01 hash of a type's description."""
    return str(TYPESTORE.hash_rihs01(type_name))


def topic_key(domain: int, topic: str, type_name: str) -> str:
    """The data key of `topic` (a fully qualified name, /a/b) carrying `type_name`."""
    name = topic.removeprefix("/").removesuffix("/")
    return f"{domain}/{name}/{dds_type(type_name)}/{type_hash(type_name)}"


def mangle(name: str) -> str:
    return name.replace("/", "%")


def _duration(time: Any) -> str:
    """A QoS duration's `s,ns`: empty fields for 0 (rclcpp's default: infinite), as rmw_zenoh's
    normalisation leaves it."""
    return "," if (time.sec, time.nsec) == (0, 0) else f"{time.sec},{time.nsec}"


def qos_string(qos: Qos) -> str:
    """The QoS field of a token."""

    def enum(value: Any, default: Any) -> str:
        return "" if value in (default, 0) else str(value.value)  # 0: the system default, i.e. rmw_zenoh's

    reliability, durability, history, liveliness = (
        enum(v, d)
        for v, d in zip(
            (qos.reliability, qos.durability, qos.history, qos.liveliness), _DEFAULTS, strict=True
        )
    )
    depth = "" if qos.depth in (0, DEFAULT_DEPTH) else str(qos.depth)
    return (
        f"{reliability}:{durability}:{history},{depth}:{_duration(qos.deadline)}:"
        f"{_duration(qos.lifespan)}:{liveliness},{_duration(qos.liveliness_lease_duration)}"
    )


@dataclass(frozen=True)
class Endpoint:
    """A node, or a publisher or subscription of one, as a liveliness token names it."""

    domain: int
    zid: str  # the session's id as Zenoh prints it (`str(session.info.zid())`)
    node_id: int
    entity_id: int
    kind: str  # NODE, PUBLISHER, SUBSCRIPTION
    namespace: str  # the node's, absolute (/ or /a/b)
    node: str
    topic: str = ""
    type_name: str = ""
    qos: Qos | None = None
    enclave: str = DEFAULT_ENCLAVE

    @property
    def token(self) -> str:
        parts = [
            LIVELINESS_PREFIX,
            str(self.domain),
            self.zid,
            str(self.node_id),
            str(self.entity_id),
            self.kind,
            mangle(self.enclave),
            mangle(self.namespace),
            self.node,
        ]
        if self.kind != NODE:
            assert self.qos is not None
            parts += [
                mangle(self.topic),
                dds_type(self.type_name),
                type_hash(self.type_name),
                qos_string(self.qos),
            ]
        return "/".join(parts)

    @property
    def gid(self) -> bytes:
        return xxhash.xxh3_128_intdigest(self.token.encode()).to_bytes(GID_BYTES, "little")


def attachment(seq: int, stamp_ns: int, gid: bytes) -> bytes:
    return ATTACHMENT.pack(seq, stamp_ns, GID_BYTES) + gid


def parse_attachment(data: bytes | None) -> tuple[int, int, bytes]:
    """(sequence number, source timestamp [ns], GID); BadInput when missing or malformed."""
    if data is None:
        raise BadInput("no attachment (rmw_zenoh's sequence number, source timestamp and GID)")
    if len(data) < ATTACHMENT.size + GID_BYTES:
        raise BadInput(f"attachment of {len(data)} bytes; rmw_zenoh's is {ATTACHMENT.size + GID_BYTES}")
    seq, stamp_ns, gid_length = ATTACHMENT.unpack_from(data)
    if gid_length != GID_BYTES:
        raise BadInput(f"attachment's GID is {gid_length} bytes, not {GID_BYTES}")
    return seq, stamp_ns, data[ATTACHMENT.size : ATTACHMENT.size + GID_BYTES]


def deserialize(payload: bytes, type_name: str) -> Any:
    """A CDR payload as a message of `type_name`; BadInput when it does not decode to one."""
    if payload[:4] not in CDR_HEADERS:
        raise BadInput(f"not CDR: encapsulation header {payload[:4].hex() or 'missing'}")
    try:
        return TYPESTORE.deserialize_cdr(payload, type_name)
    except Exception as exc:  # bytes from the network: whatever the decoder trips on, it is the bytes
        raise BadInput(f"CDR does not decode as {type_name}: {type(exc).__name__}: {exc}") from None


def _reliability(qos: Qos) -> zenoh.Reliability:
    return (
        zenoh.Reliability.BEST_EFFORT
        if qos.reliability == QosReliability.BEST_EFFORT
        else zenoh.Reliability.RELIABLE
    )


def _congestion(qos: Qos) -> zenoh.CongestionControl:
    keep_all = qos.reliability != QosReliability.BEST_EFFORT and qos.history == QosHistory.KEEP_ALL
    return zenoh.CongestionControl.BLOCK if keep_all else zenoh.CongestionControl.DROP


class Publisher:
    """A ROS 2 publisher on Zenoh: its token, its data key, each sample's attachment."""

    def __init__(self, node: Node, topic: str, type_name: str, qos: Qos) -> None:
        self.topic, self.type_name = topic, type_name
        self.endpoint = node.endpoint(PUBLISHER, topic, type_name, qos)
        self.key = topic_key(node.domain, topic, type_name)
        self.gid = self.endpoint.gid
        self.seq = 0
        self._lock = threading.Lock()
        self.transient_local = qos.durability == QosDurability.TRANSIENT_LOCAL
        if self.transient_local:  # late subscribers get the last `depth` samples from the cache
            self._publisher: Any = zenoh.ext.declare_advanced_publisher(
                node.session,
                self.key,
                reliability=_reliability(qos),
                congestion_control=_congestion(qos),
                cache=zenoh.ext.CacheConfig(max_samples=qos.depth or DEFAULT_DEPTH),
                publisher_detection=True,
                sample_miss_detection=zenoh.ext.MissDetectionConfig(heartbeat=None, sporadic_heartbeat=0.5),
            )
        else:
            self._publisher = node.session.declare_publisher(
                self.key, reliability=_reliability(qos), congestion_control=_congestion(qos)
            )
        self._token = node.session.liveliness().declare_token(self.endpoint.token)

    def put(self, payload: bytes) -> None:
        """Send a CDR payload (types.serialize) with its attachment."""
        with self._lock:
            self.seq += 1
            seq = self.seq
        self._publisher.put(payload, attachment=attachment(seq, time.time_ns(), self.gid))

    def matched(self) -> bool:
        """Whether a subscriber of the topic is known (not for a transient local one, whose
        late subscribers get its cache)."""
        return self.transient_local or bool(self._publisher.matching_status.matching)

    def close(self) -> None:
        self._token.undeclare()
        self._publisher.undeclare()


class Subscription:
    """A ROS 2 subscription on Zenoh: every sample on the topic is checked (type, type hash,
    attachment, CDR) before `on_message` gets it; `on_reject(key, reason)` gets the others."""

    def __init__(
        self,
        node: Node,
        topic: str,
        type_name: str,
        qos: Qos,
        on_message: Callable[[Any], None],
        on_reject: Callable[[str, str], None],
    ) -> None:
        self.topic, self.type_name = topic, type_name
        self.endpoint = node.endpoint(SUBSCRIPTION, topic, type_name, qos)
        self.key = topic_key(node.domain, topic, type_name)
        self.expected = (dds_type(type_name), type_hash(type_name))
        self.on_message, self.on_reject = on_message, on_reject
        prefix = self.key.rsplit("/", 2)[0]
        # any type on the topic: a wrong one is seen, counted and named, not silently missed
        self._subscriber = node.session.declare_subscriber(f"{prefix}/*/*", self._on_sample)
        self._token = node.session.liveliness().declare_token(self.endpoint.token)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        try:
            got = tuple(key.rsplit("/", 2)[1:])
            if got[0] != self.expected[0]:
                raise BadInput(f"type {got[0]}, the topic carries {self.expected[0]}")
            if got[1] != self.expected[1]:
                raise BadInput(
                    f"type hash {got[1]} is not {self.type_name}'s {self.expected[1]} "
                    "(another version of the message definition)"
                )
            attached = sample.attachment
            parse_attachment(attached.to_bytes() if attached is not None else None)
            message = deserialize(sample.payload.to_bytes(), self.type_name)
        except BadInput as exc:
            self.on_reject(self.key, str(exc))
            return
        self.on_message(message)

    def close(self) -> None:
        self._token.undeclare()
        self._subscriber.undeclare()


class Node:
    """A ROS 2 node over a Zenoh session: its token, and ids for its endpoints (one counter per
    session, as rmw_zenoh keeps one per context)."""

    def __init__(self, session: zenoh.Session, domain: int, namespace: str, name: str) -> None:
        self.session, self.domain, self.namespace, self.name = session, domain, namespace, name
        self.zid = str(session.info.zid())
        self._ids = itertools.count()
        self.id = next(self._ids)
        self.node_endpoint = self.endpoint(NODE)
        self._token = session.liveliness().declare_token(self.node_endpoint.token)
        self.endpoints: list[Publisher | Subscription] = []

    def endpoint(self, kind: str, topic: str = "", type_name: str = "", qos: Qos | None = None) -> Endpoint:
        entity_id = self.id if kind == NODE else next(self._ids)
        return Endpoint(
            self.domain, self.zid, self.id, entity_id, kind, self.namespace, self.name, topic, type_name, qos
        )

    def publisher(self, topic: str, type_name: str, qos: Qos) -> Publisher:
        publisher = Publisher(self, topic, type_name, qos)
        self.endpoints.append(publisher)
        return publisher

    def subscription(
        self,
        topic: str,
        type_name: str,
        qos: Qos,
        on_message: Callable[[Any], None],
        on_reject: Callable[[str, str], None],
    ) -> Subscription:
        subscription = Subscription(self, topic, type_name, qos, on_message, on_reject)
        self.endpoints.append(subscription)
        return subscription

    def close(self) -> None:
        for endpoint in self.endpoints:
            endpoint.close()
        self._token.undeclare()
