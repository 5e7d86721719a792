"""The onshore station: the operator. Sends the mission, follows the vehicle's telemetry
and publishes the mission status as the operator sees it."""

from __future__ import annotations

import time

import numpy as np

from common import keys
from common.bus import Bus
from common.config import Config
from common.messages import MissionStatus, Telemetry, Waypoints
from common.rate import Rate

STATUS_PERIOD_S = 0.25


def run(config: Config, bus: Bus) -> None:
    mission = config.mission
    command = Waypoints(command_id=int(time.time() * 1e3), waypoints=np.array(mission.waypoints))
    telemetry = bus.subscribe("vessel", "telemetry", maxlen=8)
    rate = Rate(STATUS_PERIOD_S, bus.stop)
    last_sent_s = -float("inf")
    status = MissionStatus(mode="idle", waypoint_index=0, waypoints_total=len(mission.waypoints),
                           position_error_m=0.0, done=False)
    taken = False
    while True:
        latest = telemetry.latest()
        if latest is not None:
            t = latest.message
            assert isinstance(t, Telemetry)
            taken = taken or t.command_id == command.command_id
            status = MissionStatus(mode=t.mode, waypoint_index=t.waypoint_index,
                                   waypoints_total=len(mission.waypoints),
                                   position_error_m=t.position_error_m,
                                   done=taken and t.mode == "reached")
        # the satellite loses packets: resend the mission until telemetry shows it taken
        if not taken and time.monotonic() - last_sent_s > mission.resend_period_s:
            bus.publish("op/waypoints", command)
            last_sent_s = time.monotonic()
        bus.observe(keys.mission_key(bus.system), status)
        if not rate.sleep():
            return
