"""The vessel station: relays telemetry to shore, downsampled for the satellite link, and
operator commands down to the vehicle."""

from __future__ import annotations

from common.bus import Bus
from common.config import Config
from common.rate import Rate


def run(config: Config, bus: Bus) -> None:
    telemetry = bus.subscribe("onboard", "telemetry", maxlen=8)
    operator = bus.subscribe("onshore", "op/waypoints")
    rate = Rate(config.vessel.telemetry_period_s, bus.stop)
    forwarded_seq = -1
    while True:
        for command in operator.drain():  # commands go down as soon as they are seen
            bus.publish("goal/waypoints", command.message)
        latest = telemetry.latest()
        if latest is not None and latest.seq != forwarded_seq:
            bus.publish("telemetry", latest.message)
            forwarded_seq = latest.seq
        if not rate.sleep():
            return
