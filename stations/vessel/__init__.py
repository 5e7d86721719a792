"""The vessel station: relays telemetry to shore, downsampled for the satellite link, and
operator commands down to the vehicle; beats a heartbeat to onboard that says whether shore
is still heard."""

from __future__ import annotations

import time

from common.bus import Bus
from common.config import Config
from common.messages import Heartbeat
from common.rate import Rate

RELAYED_DOWN = {"op/waypoints": "goal/waypoints", "op/arm": "goal/arm"}
POLL_PERIOD_S = 0.05  # how long an operator command may wait on the vessel


def run(config: Config, bus: Bus) -> None:
    cfg = config.vessel
    telemetry = bus.subscribe("onboard", "telemetry", maxlen=8)
    operator = {topic: bus.subscribe("onshore", topic) for topic in RELAYED_DOWN}
    shore_beats = bus.subscribe("onshore", "heartbeat", maxlen=4)
    rate = Rate(POLL_PERIOD_S, bus.stop)
    shore_heard_s = started_s = time.monotonic()
    last_beat_s = last_relay_s = -float("inf")
    forwarded_seq = -1
    while True:
        now_s = time.monotonic()
        for topic, inbox in operator.items():  # commands go down as soon as they are seen
            for command in inbox.drain():
                bus.publish(RELAYED_DOWN[topic], command.message)
        if shore_beats.drain():
            shore_heard_s = now_s
        if now_s - last_beat_s >= cfg.heartbeat_period_s:
            silence_s = now_s - max(shore_heard_s, started_s)
            bus.publish("heartbeat", Heartbeat(silence_s, silence_s < cfg.shore_timeout_s))
            last_beat_s = now_s
        latest = telemetry.latest()
        due = now_s - last_relay_s >= cfg.telemetry_period_s
        if due and latest is not None and latest.seq != forwarded_seq:
            bus.publish("telemetry", latest.message)
            forwarded_seq, last_relay_s = latest.seq, now_s
        if not rate.sleep():
            return
