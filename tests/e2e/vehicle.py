"""A recorded vehicle standing in for a real one in a hybrid run: a process of its own that speaks
abyss's keys with abyss's message classes, as a team's vehicle bridge does (docs/hybrid.md). It
publishes a recorded run's navigation and joints on `simulation/nav` and `simulation/joints`, each
at its recorded simulated time after its start (the navigation as the sensors gave it, or, with
`--from truth`, the simulation's truth as a fused navigation: a fix every sample), and counts the
velocity commands onboard sends it, which it does not act on (it is a recording).

    python vehicle.py RUN_DIR ENDPOINT SYSTEM REPORT [--topics nav,joints] [--from nav|truth]
        [--stop-after S]

It starts at once, stops after `--stop-after` simulated seconds of the recording (its navigation
then goes stale) or at the recording's end, and on SIGTERM writes REPORT (JSON: what it sent,
the commands it received) and ends."""

from __future__ import annotations

import argparse
import json
import signal
import threading
import time
from pathlib import Path

import zenoh

from abyss.bus.session import client_config
from abyss.interface import keys
from abyss.interface.messages import JointState, NavState, VelocityRef, decode, encode
from abyss.recording.reader import open_recording

NAV_KEY = {"nav": "simulation/nav", "truth": "simulation/truth"}


def recorded(run_dir: Path, topics: list[str], source: str) -> list[tuple[float, str, NavState | JointState]]:
    """(simulated time [s], topic, message) of the recording, in time order."""
    recording = open_recording(run_dir)
    out: list[tuple[float, str, NavState | JointState]] = []
    records = recording.published(("simulation",)) + recording.observed()
    for record, message in recording.messages(records):
        topic = record.key.split("/", 2)[2]
        if topic == NAV_KEY[source] and "nav" in topics and isinstance(message, NavState):
            out.append((message.sim_time_s, "nav", message))
        elif topic == "simulation/joints" and "joints" in topics and isinstance(message, JointState):
            out.append((message.sim_time_s, "joints", message))
    return sorted(out, key=lambda item: item[0])


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("run_dir", type=Path)
    p.add_argument("endpoint")
    p.add_argument("system")
    p.add_argument("report", type=Path)
    p.add_argument("--topics", default="nav,joints")
    p.add_argument("--from", dest="source", choices=tuple(NAV_KEY), default="nav")
    p.add_argument("--stop-after", type=float, default=float("inf"))
    args = p.parse_args()
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    messages = recorded(args.run_dir, args.topics.split(","), args.source)
    session = zenoh.open(client_config(args.endpoint))
    publishers = {
        t: session.declare_publisher(keys.spec("simulation", t).key(args.system)) for t in ("nav", "joints")
    }
    commands: list[float] = []

    def command(sample: zenoh.Sample) -> None:
        commands.append(
            decode(str(sample.key_expr), sample.payload.to_bytes(), VelocityRef).message.linear_mps_body[0]
        )

    sub = session.declare_subscriber(keys.spec("onboard", "cmd/vehicle_velocity").key(args.system), command)
    sent = {"nav": 0, "joints": 0}
    t0_sim, t0_wall = messages[0][0], time.monotonic()
    for sim_s, topic, message in messages:
        if sim_s - t0_sim > args.stop_after or stop.wait(
            max(0.0, t0_wall + sim_s - t0_sim - time.monotonic())
        ):
            break
        publishers[topic].put(encode(message, sent[topic], time.time()))
        sent[topic] += 1
    stopped_s = time.monotonic() - t0_wall
    stop.wait()
    args.report.write_text(
        json.dumps({"sent": sent, "stopped_after_s": stopped_s, "commands": len(commands)})
    )
    sub.undeclare()
    session.close()


if __name__ == "__main__":
    main()
