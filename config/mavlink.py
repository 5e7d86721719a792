"""The vehicle as a MAVLink system (the mavlink/ room): onboard speaks MAVLink 2 as ArduSub does,
and the vessel and the onshore station each serve a UDP endpoint where a ground station connects:
at the vessel it sees the tether, on shore the satellite."""

from __future__ import annotations

from dataclasses import dataclass

from abyss.common.errors import ConfigError


@dataclass(frozen=True)
class MavlinkConfig:
    # on: onboard answers as a MAVLink vehicle, the vessel and shore serve their endpoints, and the
    # mission is the ground station's (shore sends none of its own and judges the one flown)
    enabled: bool = False
    # the ground stations' endpoints: UDP, where QGroundControl, Cockpit, MAVProxy or a pymavlink
    # script sends first (udpout:HOST:PORT) and is answered; 0.0.0.0 to take ground stations from
    # other hosts
    listen_host: str = "127.0.0.1"
    onshore_port: int = 14550  # across the satellite
    vessel_port: int = 14551  # across the tether
    # ground stations each endpoint sends to from the start, HOST:PORT, as BlueOS's UDP client
    # endpoints do: QGroundControl and `udpin:` scripts listen (QGroundControl on 14550, so on one
    # host the endpoint itself moves: onshore_port = 14560, onshore_clients = ["127.0.0.1:14550"])
    onshore_clients: tuple[str, ...] = ()
    vessel_clients: tuple[str, ...] = ()
    system_id: int = 1  # the vehicle's (SYSID_THISMAV)
    gcs_system_id: int = 255  # the ground station whose heartbeat the GCS failsafe watches (SYSID_MYGCS)
    # the satellite's side a high-latency link as ArduPilot keeps one: HIGH_LATENCY2 every 5 s in
    # place of the heartbeat and the streams, until the ground station turns it off
    # (MAV_CMD_CONTROL_HIGH_LATENCY 0; MAVProxy: `link hl off`)
    satellite_high_latency: bool = True
    # ArduSub as the autopilot (docs/mavlink.md): "" is abyss's own vehicle answering as ArduSub;
    # "tcp:HOST:PORT" or "udp:HOST:PORT" is a team's ArduSub build, run by hand on the JSON physics
    # the simulation serves (json_port), whose MAVLink onboard routes to the ground stations and to
    # which it hands its goals as a companion computer does
    autopilot: str = ""
    json_port: int = 9002  # where the simulation serves ArduPilot's JSON physics, with an autopilot

    def __post_init__(self) -> None:
        for name in ("onshore_port", "vessel_port"):
            if not 1 <= getattr(self, name) <= 65535:
                raise ConfigError(f"mavlink.{name}", f"{getattr(self, name)}: a UDP port is 1 to 65535")
        if self.onshore_port == self.vessel_port:
            raise ConfigError(
                "mavlink.vessel_port",
                f"{self.vessel_port}: the same as mavlink.onshore_port; each endpoint needs its own",
            )
        if self.autopilot:
            scheme, _, address = self.autopilot.partition(":")
            if scheme not in ("tcp", "udp"):
                raise ConfigError(
                    "mavlink.autopilot",
                    f"{self.autopilot!r}: tcp:HOST:PORT or udp:HOST:PORT (ArduSub's MAVLink)",
                )
            address_of("mavlink.autopilot", address)
            if not self.enabled:
                raise ConfigError(
                    "mavlink.autopilot",
                    "an autopilot's MAVLink is routed by onboard: set mavlink.enabled too",
                )
        if not 1 <= self.json_port <= 65535:
            raise ConfigError("mavlink.json_port", f"{self.json_port}: a UDP port is 1 to 65535")
        ports = {self.onshore_port, self.vessel_port}
        for name in ("onshore_clients", "vessel_clients"):
            for i, client in enumerate(getattr(self, name)):
                host, port = address_of(f"mavlink.{name}[{i}]", client)
                if host in ("127.0.0.1", "localhost") and port in ports:
                    raise ConfigError(
                        f"mavlink.{name}[{i}]",
                        f"{client}: an endpoint's own port; move the endpoint (mavlink.*_port)",
                    )
        for name in ("system_id", "gcs_system_id"):
            if not 1 <= getattr(self, name) <= 255:
                raise ConfigError(
                    f"mavlink.{name}", f"{getattr(self, name)}: a MAVLink system id is 1 to 255"
                )
        if self.system_id == self.gcs_system_id:
            raise ConfigError("mavlink.gcs_system_id", "the same as mavlink.system_id: the vehicle's own")


def address_of(field: str, text: str) -> tuple[str, int]:
    """HOST:PORT as a UDP address; ConfigError naming `field` for anything else."""
    host, _, port = text.rpartition(":")
    if not host or not port.isdigit() or not 1 <= int(port) <= 65535:
        raise ConfigError(field, f"{text!r}: HOST:PORT, such as 127.0.0.1:14550")
    return host, int(port)
