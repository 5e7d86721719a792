"""The ground stations' endpoints: UDP, served by the vessel (the tether's side) and the onshore
station (the satellite's), as mavlink-router's server endpoints are. A ground station sends first
(QGroundControl's and Cockpit's UDP links, MAVProxy's or pymavlink's `udpout:HOST:PORT`) and is
answered from then on; whatever it sends goes to the vehicle over the bus, through the links'
emulators, and what the vehicle sends its side comes back to every ground station heard in the
last CLIENT_KEPT_S. Only whole MAVLink frames cross: bytes that are none are dropped, counted on
the key they would have gone out on, and logged with their reason. The vessel also relays the
satellite's side between onboard and shore."""

from __future__ import annotations

import logging
import socket
import time

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from abyss.bus.session import Bus
from abyss.common.errors import ConfigError
from abyss.config import Config
from abyss.config.mavlink import address_of
from abyss.interface import keys
from abyss.interface.messages import MavlinkFrames

CLIENT_KEPT_S = 10.0  # a ground station not heard for this long is no longer sent to
POLL_S = 0.01  # how long the endpoint waits on its socket before it looks at the bus
DATAGRAM_MAX = 65535
log = logging.getLogger(__name__)

# each station's endpoint: the link whose side it serves, where the vehicle's frames for it come
# from, and (the vessel) what it relays for the satellite's side
SIDES = {
    "vessel": ("tether", ("onboard", "mavlink/out")),
    "onshore": ("satellite", ("vessel", "mavlink/out")),
}


class Endpoint:
    """One station's UDP endpoint (its socket, bound at once: ConfigError naming the field if the
    port is taken) and its ground stations."""

    def __init__(self, config: Config, station: str) -> None:
        m = config.mavlink
        self.link, self.source = SIDES[station]
        port = m.vessel_port if station == "vessel" else m.onshore_port
        clients = m.vessel_clients if station == "vessel" else m.onshore_clients
        # the ground stations sent to from the start (BlueOS's UDP clients), whether heard or not
        self.fixed = [address_of(f"mavlink.{station}_clients", c) for c in clients]
        self.socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.socket.bind((m.listen_host, port))
        except OSError as exc:
            self.socket.close()
            raise ConfigError(
                f"mavlink.{station}_port", f"cannot serve UDP {m.listen_host}:{port}: {exc}"
            ) from None
        self.socket.settimeout(POLL_S)
        self.clients: dict[tuple[str, int], float] = {}  # each ground station, when last heard

    def receive(self) -> tuple[bytes, list[str]]:
        """A datagram's whole frames (b"" when none came within POLL_S) and why its other bytes
        were dropped."""
        try:
            data, address = self.socket.recvfrom(DATAGRAM_MAX)
        except TimeoutError:
            return b"", []
        if address not in self.clients:
            log.info("ground station %s:%d on the %s's side", *address, self.link)
        self.clients[address] = time.monotonic()
        parser = mavlink.MAVLink(None)  # a datagram holds whole frames: each parsed on its own
        parser.robust_parsing = True
        frames, bad = bytearray(), []
        where = f"MAVLink from {address[0]}:{address[1]}"
        for msg in parser.parse_buffer(data) or []:
            if msg.get_type() == "BAD_DATA":
                bad.append(f"{where}: {msg.reason}")
            else:
                frames += msg.get_msgbuf()
        if len(parser.buf) > parser.buf_index:  # a frame begun and not ended
            bad.append(f"{where}: a frame cut short")
        return bytes(frames), bad

    def send(self, data: bytes) -> None:
        """The vehicle's frames to the configured ground stations and every one heard lately."""
        now = time.monotonic()
        for address, heard in list(self.clients.items()):
            if now - heard > CLIENT_KEPT_S:
                del self.clients[address]
        for address in {*self.fixed, *self.clients}:
            try:
                self.socket.sendto(data, address)
            except OSError as exc:  # gone (ICMP port unreachable): it is heard again when it sends
                log.debug("ground station %s:%d: %s", *address, exc)

    def close(self) -> None:
        self.socket.close()


def serve(config: Config, bus: Bus, endpoint: Endpoint) -> None:
    """The endpoint's loop, until the bus stops: ground stations' frames to the vehicle, the
    vehicle's to them, and at the vessel the satellite's side relayed."""
    station = bus.station
    out_key = keys.spec(station, "mavlink/in").key(bus.system)
    from_vehicle = bus.subscribe(*endpoint.source, MavlinkFrames, maxlen=256)
    from_shore = (
        bus.subscribe("onshore", "mavlink/in", MavlinkFrames, maxlen=256) if station == "vessel" else None
    )
    try:
        while not bus.stop.is_set():
            data, bad = endpoint.receive()
            for reason in bad:
                bus.reject(out_key, reason)
            if data:  # a datagram's frames fit one message (DATAGRAM_MAX < MAVLINK_FRAMES_MAX_BYTES)
                bus.publish("mavlink/in", MavlinkFrames(endpoint.link, data))
            for received in from_vehicle.drain():
                if received.message.link == endpoint.link:
                    endpoint.send(received.message.data)
                elif station == "vessel":  # the satellite's side, on to shore
                    bus.publish("mavlink/out", received.message)
            if from_shore is not None:
                for received in from_shore.drain():
                    bus.publish("mavlink/in", received.message)
    finally:
        endpoint.close()
