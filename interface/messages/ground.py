"""What a ground station and the vehicle say to each other: MAVLink frames, carried over the bus
as the rest is, through the tether's and the satellite's emulators (the mavlink/ room speaks them)."""

from __future__ import annotations

from dataclasses import dataclass

from abyss.interface.messages.schema import Message, blob, scalar

# the ground station's side of the vehicle's MAVLink: the tether's end (a ground station at the
# vessel) or the satellite's (one on shore)
GROUND_LINKS = ("tether", "satellite")
MAVLINK_FRAMES_MAX_BYTES = 64 * 2**10


@dataclass(frozen=True)
class MavlinkFrames(Message):
    """Whole MAVLink frames, as a ground station or the vehicle sent them in one go, for (or from)
    the ground station at `link`'s end; the bytes are MAVLink's own (its CRC guards each frame)."""

    link: str = scalar(choices=GROUND_LINKS)
    data: bytes = blob(MAVLINK_FRAMES_MAX_BYTES)
