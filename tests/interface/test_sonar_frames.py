"""Sonar frames from the simulation's sonar to the vessel's map: on the wire (PNG and JPEG, bad
bytes refused), placed in the world as onboard places them, each beam's first echo on the arc
that holds the surface MuJoCo's ray cast meets, and the fan a viewer draws."""

from __future__ import annotations

import dataclasses
import math

import mujoco
import numpy as np
import pytest

from abyss.common.errors import BadInput
from abyss.config.simulation import SimulationConfig
from abyss.description.site import site_at
from abyss.interface.messages import SonarImage
from abyss.interface.sonar_frames import (
    arc_points,
    bearings_rad,
    decode_polar,
    echo_arcs,
    encode_polar,
    fan,
    first_echoes,
)
from abyss.stations.onboard.perception import mount_in_world
from abyss.stations.simulation.sonar import ImagingSonar
from abyss.stations.simulation.world import World

panel = site_at("").panel  # the shipped site's


def frame(beams: int = 9, bins: int = 20, fov_deg: float = 90.0) -> SonarImage:
    polar = np.zeros((bins, beams), np.uint8)
    return SonarImage(
        sonar="sonar",
        encoding="png8",
        pose_frame="world",
        beams=beams,
        bins=bins,
        range_max_m=10.0,
        horizontal_fov_rad=math.radians(fov_deg),
        vertical_aperture_rad=math.radians(20.0),
        dynamic_range_db=40.0,
        pose_sonar=np.array([1.0, 2.0, -3.0, 1.0, 0.0, 0.0, 0.0]),
        data=encode_polar(polar, "png8"),
        sim_time_s=0.0,
    )


def with_image(sonar: SonarImage, polar: np.ndarray, encoding: str = "png8") -> SonarImage:
    return dataclasses.replace(sonar, encoding=encoding, data=encode_polar(polar, encoding))


def test_first_echoes_are_the_nearest_strong_bin_per_beam() -> None:
    sonar = frame()
    polar = np.full((20, 9), 100, np.uint8)  # -24 dB everywhere: below the -15 dB threshold
    polar[12, 2] = polar[15, 2] = 250  # beam 2: two echoes, the nearer first
    polar[5, 7] = 200
    range_m, bearing_rad = first_echoes(sonar, decode_polar(with_image(sonar, polar)), -15.0)
    assert range_m == pytest.approx([12.5 * 0.5, 5.5 * 0.5])
    assert bearing_rad == pytest.approx(bearings_rad(sonar)[[2, 7]])
    assert bearings_rad(sonar)[0] == pytest.approx(math.radians(45.0))  # port first


def test_an_echo_becomes_the_arc_across_the_aperture_at_its_range() -> None:
    sonar = frame()
    points, origin = arc_points(sonar, np.array([4.0]), np.array([0.0]), spacing_m=0.1)
    assert origin == pytest.approx([1.0, 2.0, -3.0])
    assert np.linalg.norm(points - origin, axis=1) == pytest.approx(np.full(len(points), 4.0))
    assert len(points) >= math.ceil(4.0 * math.radians(20.0) / 0.1)
    elevation = np.degrees(np.arcsin((points[:, 2] - origin[2]) / 4.0))
    assert elevation.min() == pytest.approx(-10.0) and elevation.max() == pytest.approx(10.0)


def test_bad_bytes_and_sizes_are_refused_with_the_reason() -> None:
    sonar = frame()
    polar = np.random.default_rng(0).integers(0, 255, (20, 9), dtype=np.uint8)
    assert np.array_equal(decode_polar(with_image(sonar, polar)), polar)  # PNG: what the sonar sent
    assert np.abs(decode_polar(with_image(sonar, polar, "jpeg")).astype(int) - polar).mean() < 40
    with pytest.raises(BadInput, match="decodes to nothing"):
        decode_polar(dataclasses.replace(sonar, data=b"\x00not an image"))
    with pytest.raises(BadInput, match=r"expected \(20, 9\)"):
        decode_polar(with_image(sonar, np.zeros((20, 8), np.uint8)))
    with pytest.raises(BadInput, match="vehicle frame, expected the world's"):
        echo_arcs(dataclasses.replace(sonar, pose_frame="vehicle"), 0.1)


def test_the_fan_draws_each_bin_at_its_range_and_bearing() -> None:
    sonar = frame(beams=91, bins=100, fov_deg=90.0)  # a beam a degree
    polar = np.zeros((100, 91), np.uint8)
    polar[49, 60] = polar[50, 60] = polar[49, 61] = polar[50, 61] = 255  # 5 m, 15.5 deg to starboard
    image = fan(sonar, decode_polar(with_image(sonar, polar)), height_px=200)
    rows, cols = np.nonzero(image > 64)
    ahead, starboard = (200 - rows.mean()) / 20.0, (cols.mean() - image.shape[1] / 2) / 20.0  # [m]
    assert math.hypot(ahead, starboard) == pytest.approx(5.0, abs=0.1)
    assert math.degrees(math.atan2(starboard, ahead)) == pytest.approx(15.5, abs=1.0)
    assert image[0, 0] == image[0, -1] == 0  # outside the fan


def test_the_panels_echoes_lie_on_arcs_through_its_ray_cast_surface() -> None:
    """The station's frame, on the wire (PNG, as it is sent to the vessel) and placed in the
    world as onboard places it: every
    echo's arc passes within 10 cm of the point where the ray along its beam and the elevation
    of the truth meets the panel, and no arc point lies farther than the arc's own sag from the
    panel's face."""
    config = SimulationConfig(
        start_position_m_world=(1.5, 0.5, -8.0), start_yaw_rad=0.3, low_level="kinematic"
    )
    world = World(config, np.random.default_rng(0))
    sonar = ImagingSonar(world.model)
    sent = sonar.message(world.data, np.random.default_rng(1))
    truth = world.truth()
    placed = dataclasses.replace(
        sent,
        pose_frame="world",
        pose_sonar=mount_in_world(sent.pose_sonar, (truth.position_m_world, truth.orientation_wxyz_world)),
    )
    range_m, bearing_rad = first_echoes(placed, decode_polar(placed), -15.0)
    assert len(range_m) >= 10  # the plate spans a score of beams from 2.5 m
    face_x_m = panel.position_m_world[0] - panel.plate_half_size_m[0]
    site = world.data.site_xmat[sonar.site].reshape(3, 3)
    origin = world.data.site_xpos[sonar.site].copy()
    geom = np.zeros(1, np.int32)
    for r, bearing in zip(range_m, bearing_rad, strict=True):
        arc, _ = arc_points(placed, np.array([r]), np.array([bearing]), spacing_m=0.02)
        # the truth: the nearest surface along this bearing across the aperture
        hits = []
        for elevation in np.linspace(-sent.vertical_aperture_rad / 2, sent.vertical_aperture_rad / 2, 41):
            local = np.array(
                [
                    math.cos(elevation) * math.cos(bearing),
                    math.cos(elevation) * math.sin(bearing),
                    math.sin(elevation),
                ]
            )
            distance = mujoco.mj_ray(
                world.model, world.data, origin, site @ local, None, True, sonar.body, geom
            )
            if distance > 0:
                hits.append(origin + distance * (site @ local))
        nearest = min(hits, key=lambda p: float(np.linalg.norm(p - origin)))
        assert np.linalg.norm(arc - nearest, axis=1).min() < 0.1
        sag_m = r * (1 - math.cos(sent.vertical_aperture_rad))
        assert np.all(np.abs(arc[:, 0] - face_x_m) < sag_m + 0.1)
