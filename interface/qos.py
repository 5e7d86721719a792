"""How a key's messages travel over Zenoh: priority, congestion control and express by the key's
reliability and priority (`keys.KEYS`), and the transmission queue's waits for a slow link."""

from __future__ import annotations

import math
from typing import Any

import zenoh

from abyss.interface import keys

ZENOH_PRIORITY = {
    "control": zenoh.Priority.INTERACTIVE_HIGH,
    "telemetry": zenoh.Priority.DATA_HIGH,
    "bulk": zenoh.Priority.DATA_LOW,
}
LARGE_MESSAGE_BYTES = 256 * 1024  # the largest message a slow hop must carry without dropping it
ZENOH_DEFAULT_WAIT_BEFORE_DROP_S = 0.001
ZENOH_DEFAULT_WAIT_BEFORE_CLOSE_S = 5.0


def publisher_qos(spec: keys.KeySpec, lockstep: bool = False) -> dict[str, Any]:
    """The Zenoh publisher options of a data key: congestion control by its reliability (in
    lockstep always BLOCK: a station waits for every message its neighbours' links delivered),
    priority, and express (not batched) for control."""
    return {
        "congestion_control": zenoh.CongestionControl.BLOCK
        if spec.reliability == "reliable" or lockstep
        else zenoh.CongestionControl.DROP,
        "priority": ZENOH_PRIORITY[spec.priority],
        "express": spec.priority == "control",
    }


def slow_link_tuning(rate_bps: float) -> dict[str, Any]:
    """`transport/link/tx/queue/congestion_control` for a link of `rate_bps`: Zenoh drops a DROP
    message whose batches find the queue full for 1 ms, and closes the link when a BLOCK message
    waits 5 s; a 256 kB message needs 2.1 s at 1 Mbit/s, so both waits grow with the time the
    link takes to carry one large message."""
    serialise_s = 0.0 if math.isinf(rate_bps) else LARGE_MESSAGE_BYTES * 8.0 / rate_bps
    drop_us = round(1e6 * min(max(ZENOH_DEFAULT_WAIT_BEFORE_DROP_S, serialise_s), 5.0))
    close_us = round(1e6 * max(ZENOH_DEFAULT_WAIT_BEFORE_CLOSE_S, 10.0 * serialise_s))
    return {
        "drop": {"wait_before_drop": drop_us, "max_wait_before_drop_fragments": max(drop_us, 50_000)},
        "block": {"wait_before_close": close_us},
    }
