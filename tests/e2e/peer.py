"""A Zenoh peer the namespace test runs on one of its hosts (`python tests/e2e/peer.py ...`).

watch ENDPOINT SYSTEM TIMEOUT_S: a tool's client session; waits until shore reports the mission
  done and the simulation's truth has arrived (three routed hops away); prints what it saw as JSON.
intrude ENDPOINT SYSTEM HOLDER|none COUNT: a peer with HOLDER's certificate (none: without one)
  publishes COUNT waypoint commands as if it were the vessel; prints how many peers it reached.
receive LISTEN SECONDS [ALL]: counts the messages on large/** for SECONDS (from the first one's
  arrival), or until ALL have arrived (no more are sent: nothing is left to count).
send CONNECT COUNT BYTES TUNED_FOR_BPS [UNTIL_FILE]: publishes COUNT messages of BYTES on large/N with
  congestion control DROP, the transmission queue tuned for a link of TUNED_FOR_BPS (inf: Zenoh's
  defaults); keeps its session open 30 s for the queue to drain, or until UNTIL_FILE exists (the
  receiver has counted)."""

from __future__ import annotations

import json
import math
import os
import sys
import threading
import time
from pathlib import Path

import numpy as np
import zenoh

from abyss.bus.session import client_config, message_of, open_session, zenoh_config
from abyss.interface import keys
from abyss.interface.messages import MissionStatus, Waypoints, encode
from abyss.security.access import TLS_DIR_ENV, tls_settings
from abyss.security.certs import CertFiles


def watch(endpoint: str, system: str, timeout_s: float) -> dict[str, object]:
    seen: dict[str, object] = {"mission_done": False, "truth": 0, "waypoint_index": -1}
    done = threading.Event()

    def on_mission(sample: zenoh.Sample) -> None:
        status = message_of(sample, MissionStatus)
        if status is not None:
            seen["waypoint_index"] = status.waypoint_index
            if status.done:
                seen["mission_done"] = True
                done.set()

    def on_truth(_sample: zenoh.Sample) -> None:
        seen["truth"] = int(seen["truth"]) + 1  # type: ignore[call-overload]

    session = open_session(client_config(endpoint), "watch")
    subscribers = [
        session.declare_subscriber(keys.mission_key(system), on_mission),
        session.declare_subscriber(keys.truth_key(system), on_truth),
    ]
    done.wait(timeout_s)
    for subscriber in subscribers:
        subscriber.undeclare()
    session.close()
    return seen


def intrude(endpoint: str, system: str, holder: str, count: int) -> dict[str, object]:
    config = zenoh.Config()  # by hand: zenoh_config would refuse a tls/ endpoint without certificates
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("connect/endpoints", json.dumps([endpoint]))
    if holder != "none":
        config.insert_json5(
            "transport/link/tls", json.dumps(tls_settings(CertFiles(Path(os.environ[TLS_DIR_ENV]), holder)))
        )
    else:  # a TLS client that shows no certificate of its own
        config.insert_json5(
            "transport/link/tls",
            json.dumps(
                {
                    "root_ca_certificate": str(Path(os.environ[TLS_DIR_ENV]) / "ca.pem"),
                    "verify_name_on_connect": False,
                }
            ),
        )
    session = zenoh.open(config)
    time.sleep(2.0)
    peers = len(list(session.info.peers_zid())) + len(list(session.info.routers_zid()))
    rogue = Waypoints(command_id=999_999, waypoints=np.array([[50.0, 50.0, -2.0, 0.0]]))
    for seq in range(count):
        session.put(keys.spec("vessel", "goal/waypoints").key(system), encode(rogue, seq, time.time()))
        time.sleep(0.1)
    time.sleep(1.0)
    session.close()
    return {"peers": peers, "sent": count}


def receive(listen: str, seconds: float, every: float = math.inf) -> dict[str, object]:
    got: list[float] = []
    arrived = threading.Event()

    def on_sample(_sample: zenoh.Sample) -> None:
        got.append(time.monotonic())
        if len(got) >= every:
            arrived.set()

    session = open_session(zenoh_config(listen=[listen]), "receive")
    subscriber = session.declare_subscriber("large/**", on_sample)
    deadline = time.monotonic() + 60.0
    while not got and time.monotonic() < deadline:
        time.sleep(0.05)
    if got:
        arrived.wait(max(0.0, got[0] + seconds - time.monotonic()))
    subscriber.undeclare()
    session.close()
    return {"received": len(got), "span_s": got[-1] - got[0] if got else 0.0}


def send(
    connect: str,
    count: int,
    size: int,
    tuned_for_bps: float,
    until: Path | None = None,
) -> dict[str, object]:
    session = open_session(zenoh_config(connect=[connect], slowest_rate_bps=tuned_for_bps), "send")
    publisher = session.declare_publisher("large/data", congestion_control=zenoh.CongestionControl.DROP)
    time.sleep(1.0)
    for _ in range(count):
        publisher.put(bytes(size))
        time.sleep(0.1)
    deadline = time.monotonic() + 30.0  # the session's queue drains before it closes
    while time.monotonic() < deadline and not (until is not None and until.exists()):
        time.sleep(0.05)
    session.close()
    return {"sent": count}


if __name__ == "__main__":
    verb, args = sys.argv[1], sys.argv[2:]
    if verb == "watch":
        result = watch(args[0], args[1], float(args[2]))
    elif verb == "intrude":
        result = intrude(args[0], args[1], args[2], int(args[3]))
    elif verb == "receive":
        result = receive(args[0], float(args[1]), *(float(a) for a in args[2:3]))
    else:
        result = send(args[0], int(args[1]), int(args[2]), float(args[3]), *(Path(a) for a in args[4:5]))
    print(json.dumps(result))
