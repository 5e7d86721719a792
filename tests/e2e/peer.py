"""A Zenoh peer the namespace test runs on one of its hosts (`python tests/e2e/peer.py ...`).

watch ENDPOINT SYSTEM TIMEOUT_S: a tool's client session; waits until shore reports the mission
  done and the simulation's truth has arrived (three routed hops away); prints what it saw as JSON.
intrude ENDPOINT SYSTEM HOLDER|none COUNT: a peer with HOLDER's certificate (none: without one)
  publishes COUNT waypoint commands as if it were the vessel; prints how many peers it reached."""

from __future__ import annotations

import json
import os
import sys
import threading
import time
from pathlib import Path

import numpy as np
import zenoh

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from common import keys
from common.bus import client_config, message_of, open_session
from common.certs import CertFiles
from common.messages import MissionStatus, Waypoints, encode
from common.security import TLS_DIR_ENV, tls_settings


def watch(endpoint: str, system: str, timeout_s: float) -> dict[str, object]:
    seen: dict[str, object] = {"mission_done": False, "truth": 0, "waypoint_index": -1}
    done = threading.Event()

    def on_mission(sample: zenoh.Sample) -> None:
        status = message_of(sample, "MissionStatus")
        if isinstance(status, MissionStatus):
            seen["waypoint_index"] = status.waypoint_index
            if status.done:
                seen["mission_done"] = True
                done.set()

    def on_truth(_sample: zenoh.Sample) -> None:
        seen["truth"] = int(seen["truth"]) + 1  # type: ignore[call-overload]

    session = open_session(client_config(endpoint), "watch")
    subscribers = [session.declare_subscriber(keys.mission_key(system), on_mission),
                   session.declare_subscriber(keys.truth_key(system), on_truth)]
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
        config.insert_json5("transport/link/tls",
                            json.dumps(tls_settings(CertFiles(Path(os.environ[TLS_DIR_ENV]), holder))))
    else:  # a TLS client that shows no certificate of its own
        config.insert_json5("transport/link/tls", json.dumps({
            "root_ca_certificate": str(Path(os.environ[TLS_DIR_ENV]) / "ca.pem"),
            "verify_name_on_connect": False}))
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


if __name__ == "__main__":
    verb, args = sys.argv[1], sys.argv[2:]
    if verb == "watch":
        result = watch(args[0], args[1], float(args[2]))
    else:
        result = intrude(args[0], args[1], args[2], int(args[3]))
    print(json.dumps(result))
