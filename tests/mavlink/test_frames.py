"""The site's frame on the Earth (mavlink.geodesy), the vehicle's state in MAVLink's frames and
units (mavlink.streams), and a ground stations' endpoint on a real UDP socket (mavlink.endpoint):
whole frames through, the rest dropped with its reason, answers to whoever was heard."""

from __future__ import annotations

import math
import socket
from collections.abc import Iterator

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from abyss.common.errors import ConfigError
from abyss.common.geometry import quat_wxyz_of, rotation_of_rpy
from abyss.config import load
from abyss.description.site import SiteDatum
from abyss.interface.messages import NavState
from abyss.mavlink import streams
from abyss.mavlink.ardusub import SubMode
from abyss.mavlink.endpoint import Endpoint
from abyss.mavlink.geodesy import Geodesy

MAVLINK = ("mavlink.enabled=true", "time.mode=real", "mavlink.vessel_port=1")  # the vessel's: not opened here
MARSEILLE = SiteDatum(latitude_deg=43.2951, longitude_deg=5.37, surface_amsl_m=0.0, x_bearing_deg=90.0)


def test_the_world_frame_lies_east_north_up_on_its_datum_and_back_within_a_millimetre() -> None:
    g = Geodesy(MARSEILLE)
    assert g.ned_of(np.array([3.0, 4.0, -5.0])) == pytest.approx([4.0, 3.0, 5.0])  # x east, y north
    lat, lon, alt = g.geodetic_of(np.array([0.0, 1000.0, -8.0]))
    assert lat - MARSEILLE.latitude_deg == pytest.approx(1000.0 / 111_100.0, rel=2e-3)  # a km north
    assert lon == pytest.approx(MARSEILLE.longitude_deg) and alt == pytest.approx(-8.0)
    for point in ([1200.0, -800.0, -30.0], [-5.0, 2.0, -1.0]):
        back = g.world_of_geodetic(*g.geodetic_of(np.array(point)))
        assert np.abs(back - point).max() < 1e-3
    assert math.degrees(g.heading_rad(0.0)) == pytest.approx(90.0)  # facing x: east
    assert g.yaw_rad(math.radians(90.0)) == pytest.approx(0.0)
    turned = Geodesy(SiteDatum(x_bearing_deg=0.0))  # x north: y west
    assert turned.ned_of(np.array([0.0, 1.0, 0.0])) == pytest.approx([0.0, -1.0, 0.0])


def report(estimate: NavState) -> streams.Report:
    return streams.Report(1000, SubMode.ALT_HOLD, True, mavlink.MAV_STATE_ACTIVE, estimate, None, 0, 0, None)


def test_the_state_goes_out_in_mavlinks_frames_and_units() -> None:
    g = Geodesy(MARSEILLE)
    nose_up = quat_wxyz_of(
        rotation_of_rpy(0.1, -0.2, 0.3)
    )  # forward-left-up: a negative pitch lifts the nose
    estimate = NavState(
        np.array([2.0, 1.0, -10.0]), nose_up, np.array([0.5, 0.0, 0.1]), np.array([0.01, 0.02, 0.03]), 5.0
    )
    attitude = streams.attitude(report(estimate), g)
    assert (attitude.roll, attitude.pitch) == pytest.approx((0.1, 0.2))
    assert attitude.yaw == pytest.approx(math.radians(90.0) - 0.3)  # from north, clockwise
    assert (attitude.rollspeed, attitude.pitchspeed, attitude.yawspeed) == pytest.approx((0.01, -0.02, -0.03))
    position = streams.global_position_int(report(estimate), g)
    assert position.relative_alt == -10_000 and position.alt == -10_000  # [mm]: 10 m down
    assert position.hdg == round(math.degrees(math.radians(90.0) - 0.3) * 100)
    local = streams.local_position_ned(report(estimate), g)
    assert (local.x, local.y, local.z) == pytest.approx((1.0, 2.0, 10.0))
    depth = streams.scaled_pressure2(report(estimate))
    assert depth.press_abs == pytest.approx(1013.25 + 1005.2, abs=0.1)  # 10 m of sea water
    hb = streams.heartbeat(report(estimate))
    assert hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED and hb.custom_mode == 2
    hl2 = streams.high_latency2(report(estimate), g)
    assert hl2.custom_mode == 2 and hl2.custom0 & 0xFF == hb.base_mode  # base_mode in custom0, as ArduPilot


@pytest.fixture
def endpoint() -> Iterator[Endpoint]:
    port = _free_port()
    made = Endpoint(load(None, [*MAVLINK, f"mavlink.onshore_port={port}"]), "onshore")
    yield made
    made.close()


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_an_endpoint_passes_whole_frames_drops_the_rest_and_answers_who_it_heard(endpoint: Endpoint) -> None:
    frame = mavlink.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3).pack(mavlink.MAVLink(None, 255, 190))
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as gcs:
        gcs.settimeout(2.0)
        address = endpoint.socket.getsockname()
        gcs.sendto(b"noise" + frame + frame[:7], address)
        data, bad = endpoint.receive()
        assert data == frame
        assert any("Bad prefix" in r or "invalid" in r.lower() for r in bad) and any(
            "cut short" in r for r in bad
        )
        endpoint.send(b"to the ground station")
        assert gcs.recvfrom(100)[0] == b"to the ground station"
    assert endpoint.receive() == (b"", [])  # nothing within its poll


def test_an_endpoint_whose_port_is_taken_names_the_field(endpoint: Endpoint) -> None:
    taken = endpoint.socket.getsockname()[1]
    config = load(None, [*MAVLINK, f"mavlink.onshore_port={taken}"])
    with pytest.raises(ConfigError) as error:
        Endpoint(config, "onshore")
    assert error.value.field == "mavlink.onshore_port"


def test_an_endpoint_sends_to_its_configured_ground_stations_from_the_start() -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as qgc:  # listening, as QGroundControl on 14550
        qgc.bind(("127.0.0.1", 0))
        qgc.settimeout(2.0)
        listening = qgc.getsockname()[1]
        port = _free_port()
        config = load(
            None,
            [*MAVLINK, f"mavlink.onshore_port={port}", f'mavlink.onshore_clients=["127.0.0.1:{listening}"]'],
        )
        endpoint = Endpoint(config, "onshore")
        try:
            endpoint.send(b"heartbeat")
            assert qgc.recvfrom(100)[0] == b"heartbeat"
        finally:
            endpoint.close()


@pytest.mark.parametrize(
    ("client", "reason"),
    [("14550", "HOST:PORT"), ("127.0.0.1:99999", "HOST:PORT"), ("127.0.0.1:14550", "an endpoint's own port")],
)
def test_a_bad_ground_station_address_names_the_field(client: str, reason: str) -> None:
    with pytest.raises(ConfigError) as error:
        load(None, [*MAVLINK, f'mavlink.onshore_clients=["{client}"]'])
    assert error.value.field == "mavlink.onshore_clients[0]" and reason in error.value.reason
