"""A hybrid run (`[hybrid]`, `abyss up --hybrid nav,joints`): a real vehicle provides some of the
simulation's outputs, and the simulation station runs as its twin (stations/simulation/twin.py),
rendering the rest at the real vehicle's pose on the virtual site. Every output of the
simulation has one provider in a run: `providers()` says which, and a topic named by both or by
neither is refused here, at start."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from abyss.common.errors import ConfigError
from abyss.common.geometry import quat_multiply
from abyss.config.fields import positive
from abyss.interface import keys
from abyss.interface.messages import Image, SonarImage

Provider = str  # "simulation" (all-simulated), "vehicle" (the real one) or "twin"
# the simulation's outputs, `<topic>` of `simulation/<topic>`
OUTPUTS: tuple[str, ...] = tuple(s.topic for s in keys.KEYS if s.station == "simulation")
# what the twin can provide: the sensors it renders (cameras, sonar); it runs no dynamics, so the
# navigation and the joints are the real vehicle's
RENDERED: tuple[str, ...] = tuple(
    s.topic for s in keys.KEYS if s.station == "simulation" and s.message_class in (Image, SonarImage)
)

# what a ROS 2 vehicle driver provides through the gateway (`--ros2 simulation`: nav_msgs/Odometry
# and sensor_msgs/JointState, ros2.from_ros)
ROS2_VEHICLE: tuple[str, ...] = ("nav", "joints")


def _topics(field: str, topics: tuple[str, ...]) -> None:
    for topic in topics:
        if topic not in OUTPUTS:
            raise ConfigError(
                field, f"{topic!r} is not an output of the simulation; allowed: {', '.join(OUTPUTS)}"
            )
    if len(set(topics)) != len(topics):
        raise ConfigError(field, f"{', '.join(topics)}: a topic named twice")


@dataclass(frozen=True)
class HybridConfig:
    """Who provides the simulation's outputs, and where the virtual site lies in the real vehicle's
    navigation frame (its registration: the site's origin there, and the heading of its x axis)."""

    # the simulation's topics the real vehicle provides (e.g. nav, joints, sonar); () all-simulated
    vehicle: tuple[str, ...] = ()
    # those the twin renders; () every sensor the vehicle does not provide (the cameras by default)
    twin: tuple[str, ...] = ()
    # the site's origin in the vehicle's navigation frame [m] and its x axis's heading there [rad,
    # about z]: the twin renders the site so registered (the site's own [config] or --site-pose)
    site_origin_m_nav: tuple[float, float, float] = (0.0, 0.0, 0.0)
    site_heading_rad: float = 0.0
    # [s] navigation older than this (by its arrival) stops the twin's sensors: they render nothing
    # rather than from a pose that is no longer true
    nav_max_age_s: float = 0.5

    def __post_init__(self) -> None:
        _topics("hybrid.vehicle", self.vehicle)
        _topics("hybrid.twin", self.twin)
        positive("hybrid.nav_max_age_s", self.nav_max_age_s)
        if not all(math.isfinite(v) for v in (*self.site_origin_m_nav, self.site_heading_rad)):
            raise ConfigError("hybrid.site_origin_m_nav", "the registration must be finite")
        if not self.vehicle:
            if self.twin:
                raise ConfigError(
                    "hybrid.twin", "a twin needs a real vehicle: name what it provides in hybrid.vehicle"
                )
            return
        both = [t for t in self.twin if t in self.vehicle]
        if both:
            raise ConfigError(
                "hybrid.twin",
                f"{', '.join(both)}: two providers, the real vehicle (hybrid.vehicle) and the twin "
                "(hybrid.twin)",
            )
        dynamic = [t for t in self.twin if t not in RENDERED]
        if dynamic:
            raise ConfigError(
                "hybrid.twin",
                f"{', '.join(dynamic)}: the twin runs no dynamics and renders only {', '.join(RENDERED)}",
            )
        none = [t for t in OUTPUTS if t not in self.vehicle and t not in self.twin_topics]
        if none:
            raise ConfigError(
                "hybrid.vehicle",
                f"{', '.join(none)}: no provider (onboard takes every output of the simulation); the "
                f"twin renders only {', '.join(RENDERED)}, so the real vehicle must provide the rest",
            )

    @property
    def on(self) -> bool:
        """A hybrid run: a real vehicle takes part."""
        return bool(self.vehicle)

    @property
    def twin_topics(self) -> tuple[str, ...]:
        """What the twin renders: its own list, else every sensor the vehicle does not provide."""
        return self.twin or tuple(t for t in RENDERED if t not in self.vehicle)

    def providers(self) -> dict[str, Provider]:
        """Each output of the simulation (`simulation/<topic>`) and who provides it in this run."""
        if not self.on:
            return {t: "simulation" for t in OUTPUTS}
        return {t: "vehicle" if t in self.vehicle else "twin" for t in OUTPUTS}

    def site_pose(
        self, position_m_nav: np.ndarray, orientation_wxyz_nav: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """A pose in the vehicle's navigation frame in the site's frame (the registration undone)."""
        c, s = math.cos(self.site_heading_rad), math.sin(self.site_heading_rad)
        turn = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])  # nav -> site, about z
        position = turn @ (np.asarray(position_m_nav, dtype=float) - np.asarray(self.site_origin_m_nav))
        half = -self.site_heading_rad / 2  # the heading taken off
        orientation = quat_multiply(
            np.array([math.cos(half), 0.0, 0.0, math.sin(half)]), orientation_wxyz_nav
        )
        return position, orientation

    def nav_pose(
        self, position_m_site: np.ndarray, orientation_wxyz_site: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """A pose in the site's frame in the vehicle's navigation frame (the registration applied,
        `site_pose` undone). With no registration, or no real vehicle, the pose as given, untouched:
        the all-simulated runs' numbers stay bit for bit what they were."""
        if not self.on or (self.site_heading_rad == 0.0 and not any(self.site_origin_m_nav)):
            return position_m_site, orientation_wxyz_site
        c, s = math.cos(self.site_heading_rad), math.sin(self.site_heading_rad)
        turn = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])  # site -> nav, about z
        position = turn @ np.asarray(position_m_site, dtype=float) + np.asarray(self.site_origin_m_nav)
        half = self.site_heading_rad / 2  # the heading put on
        orientation = quat_multiply(
            np.array([math.cos(half), 0.0, 0.0, math.sin(half)]), orientation_wxyz_site
        )
        return position, orientation
