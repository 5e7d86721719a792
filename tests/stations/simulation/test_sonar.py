"""The imaging sonar: the panel and the seabed at the range and bearing MuJoCo's own ray casts
give, seeded speckle."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from abyss.config.simulation import SimulationConfig
from abyss.stations.simulation.sonar import ImagingSonar, SonarSpec
from abyss.stations.simulation.world import World


def world_at(position: tuple[float, float, float], yaw_rad: float) -> World:
    config = SimulationConfig(start_position_m_world=position, start_yaw_rad=yaw_rad, low_level="kinematic")
    return World(config, np.random.default_rng(0))


def truth_range_m(
    world: World, sonar: ImagingSonar, bearing_rad: float, elevation_rad: float = 0.0, body: str = ""
) -> float:
    """One mj_ray from the sonar along a bearing, as the ground truth; with `body`, the ray must
    end on that body's geoms."""
    d = world.data
    rotation = d.site_xmat[sonar.site].reshape(3, 3)
    local = np.array(
        [
            math.cos(elevation_rad) * math.cos(bearing_rad),
            math.cos(elevation_rad) * math.sin(bearing_rad),
            math.sin(elevation_rad),
        ]
    )
    geom = np.zeros(1, np.int32)
    origin = d.site_xpos[sonar.site].copy()
    distance = float(mujoco.mj_ray(world.model, d, origin, rotation @ local, None, True, sonar.body, geom))
    if body:
        assert world.model.body(int(world.model.geom_bodyid[geom[0]])).name == body
    return distance


def strongest_range_m(image: np.ndarray, spec: SonarSpec, beam: int) -> float:
    return (int(np.argmax(image[:, beam])) + 0.5) * spec.bin_m()


@pytest.mark.parametrize("yaw_deg", [0.0, 25.0, -40.0])
def test_the_panel_appears_at_its_ray_cast_range_and_bearing(yaw_deg: float) -> None:
    """The vehicle 3 m off the panel, turned away by yaw: the panel's echo is at the bearing
    -yaw and at the range a ray along that bearing meets it (within two bins)."""
    world = world_at((2.0, 0.0, -8.5), math.radians(yaw_deg))
    spec = SonarSpec()
    sonar = ImagingSonar(world.model, spec)
    image = sonar.image(world.data, np.random.default_rng(0))
    bearing = -math.radians(yaw_deg)
    beam = int(np.argmin(np.abs(spec.bearings_rad() - bearing)))
    expected_m = truth_range_m(world, sonar, spec.bearings_rad()[beam], body="panel")
    assert strongest_range_m(image, spec, beam) == pytest.approx(expected_m, abs=2 * spec.bin_m())
    # the panel's columns are where its edges are: the strongest beam overall lies within the panel
    near, far = round((expected_m - 0.3) / spec.bin_m()), round((expected_m + 0.3) / spec.bin_m())
    wall = image[near:far].sum(axis=0)
    strongest = spec.bearings_rad()[int(np.argmax(wall))]
    half_width_rad = math.atan2(0.8, expected_m)  # the plate is 1.6 m wide
    assert abs(strongest - bearing) < half_width_rad


def test_the_seabed_appears_where_the_beams_meet_it() -> None:
    """Far from the panel, looking away from it: the echo in the middle beam starts where the
    lowest ray of the aperture meets the seabed."""
    world = world_at((0.0, 0.0, -8.0), math.pi)
    spec = SonarSpec()
    sonar = ImagingSonar(world.model, spec)
    image = sonar.image(world.data, np.random.default_rng(0))
    beam = spec.beams // 2
    nearest_m = truth_range_m(
        world, sonar, spec.bearings_rad()[beam], -spec.vertical_aperture_rad / 2, body="world"
    )  # the seabed is a world geom
    assert nearest_m < spec.range_max_m
    column = image[:, beam].astype(float)
    first_echo = int(np.argmax(column > 0.5 * column.max())) * spec.bin_m()
    assert first_echo == pytest.approx(nearest_m, abs=0.5)
    assert column[: int(0.8 * nearest_m / spec.bin_m())].max() < 0.5 * column.max()  # open water before it


def test_speckle_is_seeded() -> None:
    world = world_at((2.0, 0.0, -8.5), 0.0)
    sonar = ImagingSonar(world.model)
    a = sonar.image(world.data, np.random.default_rng(3))
    assert np.array_equal(a, sonar.image(world.data, np.random.default_rng(3)))
    assert not np.array_equal(a, sonar.image(world.data, np.random.default_rng(4)))
