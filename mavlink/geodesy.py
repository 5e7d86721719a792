"""The site's world frame (z up) on the Earth, as MAVLink speaks of position: north-east-down
from the site's origin (LOCAL_POSITION_NED) and WGS-84 latitude and longitude (GLOBAL_POSITION_INT,
mission items), on a plane tangent at the site's datum (description.site.SiteDatum): a few
kilometres' work site is flat to millimetres."""

from __future__ import annotations

import math

import numpy as np

from abyss.description.site import SiteDatum

WGS84_A_M = 6378137.0  # the semi-major axis
WGS84_E2 = 6.69437999014e-3  # the first eccentricity squared


class Geodesy:
    def __init__(self, datum: SiteDatum) -> None:
        self.datum = datum
        bearing = math.radians(datum.x_bearing_deg)
        self._cos, self._sin = math.cos(bearing), math.sin(bearing)
        lat = math.radians(datum.latitude_deg)
        w = 1.0 - WGS84_E2 * math.sin(lat) ** 2
        self.north_m_per_rad = WGS84_A_M * (1.0 - WGS84_E2) / w**1.5  # the meridian's radius
        self.east_m_per_rad = WGS84_A_M / math.sqrt(w) * math.cos(lat)  # the parallel's

    def ned_of(self, position_m_world: np.ndarray) -> np.ndarray:
        """North, east, down [m] from the origin."""
        x, y, z = (float(v) for v in position_m_world)
        return np.array([x * self._cos + y * self._sin, x * self._sin - y * self._cos, -z])

    def world_of(self, ned_m: np.ndarray) -> np.ndarray:
        """The world frame's x, y, z [m] of north, east, down [m]."""
        north, east, down = (float(v) for v in ned_m)
        return np.array([north * self._cos + east * self._sin, north * self._sin - east * self._cos, -down])

    def heading_rad(self, yaw_rad: float) -> float:
        """The heading [rad, clockwise from north, 0..2 pi] of a yaw about the world's z [rad]."""
        return (math.radians(self.datum.x_bearing_deg) - yaw_rad) % (2.0 * math.pi)

    def yaw_rad(self, heading_rad: float) -> float:
        """The yaw about the world's z [rad, -pi..pi] of a heading [rad, clockwise from north]."""
        return math.remainder(math.radians(self.datum.x_bearing_deg) - heading_rad, 2.0 * math.pi)

    def geodetic_of(self, position_m_world: np.ndarray) -> tuple[float, float, float]:
        """Latitude, longitude [deg] and altitude above mean sea level [m]."""
        north, east, down = self.ned_of(position_m_world)
        return (
            self.datum.latitude_deg + math.degrees(north / self.north_m_per_rad),
            self.datum.longitude_deg + math.degrees(east / self.east_m_per_rad),
            self.datum.surface_amsl_m - down,
        )

    def world_of_geodetic(
        self, latitude_deg: float, longitude_deg: float, altitude_amsl_m: float
    ) -> np.ndarray:
        """The world frame's x, y, z [m] of a latitude, longitude [deg] and altitude [m, AMSL]."""
        north = math.radians(latitude_deg - self.datum.latitude_deg) * self.north_m_per_rad
        east = math.radians(longitude_deg - self.datum.longitude_deg) * self.east_m_per_rad
        return self.world_of(np.array([north, east, self.datum.surface_amsl_m - altitude_amsl_m]))
