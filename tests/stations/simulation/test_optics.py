"""The underwater optics on the real world's render: for each Jerlov water type, the contrast of
the panel's markers falls with the light's path (lamps -> marker -> camera) as the type's
attenuation says; marine snow and noise come from the generator; the depth camera is left alone;
a water type that does not exist fails the configuration."""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import mujoco
import numpy as np
import pytest

from abyss.common.errors import ConfigError
from abyss.config.simulation import WATER_TYPES as CONFIG_WATER_TYPES
from abyss.config.simulation import SimulationConfig
from abyss.description.robot import robot_at
from abyss.description.site import site_at, world_model
from abyss.stations.simulation.optics import WATER_TYPES, Optics, WaterType, range_of_depth
from abyss.stations.simulation.rendering import Cameras, lamps_of

ROBOT = robot_at("")  # the shipped robot package
panel = site_at("").panel  # the shipped site's


pytestmark = pytest.mark.timeout(300)
WIDTH_PX, HEIGHT_PX = 640, 480
FARTHEST_M = 4.0  # or where the light's path has lost exp(-4) of it in the type's bluest channel
MARKER = 0  # a large one, in the panel's top left corner as the vehicle sees it
CLEAR = WaterType("clear", (0.0, 0.0, 0.0), 0.0)  # no attenuation, no scattering: the lamps alone


@pytest.fixture(scope="module")
def world() -> tuple[mujoco.MjModel, mujoco.MjData, Cameras]:
    model = world_model(ROBOT, site_at(""))
    cameras = Cameras(model, WIDTH_PX, HEIGHT_PX, depth_camera=ROBOT.depth_camera)
    yield model, mujoco.MjData(model), cameras
    cameras.close()


def marker_m_world() -> np.ndarray:
    y, z, _ = panel.marker_table[MARKER]
    return np.array(panel.position_m_world) + np.array((-panel.plate_half_size_m[0], y, z))


def look_at_marker(model: mujoco.MjModel, data: mujoco.MjData, range_m: float) -> None:
    """The vehicle pitched up by its cameras' 20 degrees, cam_left `range_m` in front of the
    marker, looking at it square on."""
    data.qpos[:] = 0
    data.qpos[3:7] = (np.cos(np.radians(-10)), 0.0, np.sin(np.radians(-10)), 0.0)
    mujoco.mj_forward(model, data)
    offset = data.cam_xpos[model.camera("cam_left").id] - data.qpos[:3]
    data.qpos[:3] = marker_m_world() - (range_m, 0.0, 0.0) - offset
    mujoco.mj_forward(model, data)


def marker_contrast(radiance: np.ndarray, plain: np.ndarray, focal_px: float, range_m: float) -> np.ndarray:
    """White minus black [per channel] over the marker's pixels, told apart in the plain render."""
    half_px = int(0.5 * panel.marker_table[MARKER][2] * focal_px / range_m)
    rows = slice(HEIGHT_PX // 2 - half_px, HEIGHT_PX // 2 + half_px)
    cols = slice(WIDTH_PX // 2 - half_px, WIDTH_PX // 2 + half_px)
    gray = plain[rows, cols].mean(axis=-1)
    white, black = gray > 150, gray < 60
    assert white.sum() > 10 and black.sum() > 10, "the marker is not in the middle of the image"
    window = radiance[rows, cols]
    return window[white].mean(axis=0) - window[black].mean(axis=0)


@pytest.mark.parametrize("name", list(WATER_TYPES))
def test_marker_contrast_falls_with_the_configured_attenuation(
    world: tuple[mujoco.MjModel, mujoco.MjData, Cameras], name: str
) -> None:
    model, data, cameras = world
    intrinsics = cameras.intrinsics("cam_left")
    lamps = lamps_of(model, "cam_left")
    water, clear = Optics(WATER_TYPES[name], intrinsics, lamps), Optics(CLEAR, intrinsics, lamps)
    paths_m, log_ratios = [], []
    farthest_m = min(FARTHEST_M, 2.0 / max(WATER_TYPES[name].attenuation_per_m))
    for range_m in np.linspace(1.0, farthest_m, 5):
        look_at_marker(model, data, range_m)
        plain = cameras.plain_rgb(data, "cam_left")
        ranges = range_of_depth(cameras.depth_m(data, "cam_left"), intrinsics)
        ratio = marker_contrast(
            water.radiance(plain, ranges), plain, intrinsics.fx_px, range_m
        ) / marker_contrast(clear.radiance(plain, ranges), plain, intrinsics.fx_px, range_m)
        lamps_m = [
            np.linalg.norm(data.light_xpos[model.light(n).id] - marker_m_world())
            for n in ("headlight_left", "headlight_right")
        ]
        paths_m.append(range_m + np.mean(lamps_m))  # lamps -> marker -> camera
        log_ratios.append(np.log(ratio))
    slopes = -np.polyfit(paths_m, np.array(log_ratios), 1)[0]  # per channel [1/m]
    expected = np.array(WATER_TYPES[name].attenuation_per_m)
    assert np.allclose(slopes, expected, rtol=0.05, atol=0.005), (slopes, expected)


def test_the_water_types_are_the_configurations() -> None:
    assert set(CONFIG_WATER_TYPES) == {"none", *WATER_TYPES}


def test_a_water_type_that_does_not_exist_fails_the_configuration() -> None:
    with pytest.raises(ConfigError, match=r"simulation\.water.*9C"):
        SimulationConfig(water="10C")
    with pytest.raises(ConfigError, match=r"simulation\.marine_snow"):
        SimulationConfig(marine_snow=-1.0)


def test_snow_and_noise_come_from_the_generator(world: tuple[mujoco.MjModel, mujoco.MjData, Cameras]) -> None:
    model, data, cameras = world
    look_at_marker(model, data, 2.0)
    plain = cameras.plain_rgb(data, "cam_left")
    ranges = range_of_depth(cameras.depth_m(data, "cam_left"), cameras.intrinsics("cam_left"))
    optics = Optics(WATER_TYPES["7C"], cameras.intrinsics("cam_left"), lamps_of(model, "cam_left"))
    first = optics.image(plain, ranges, np.random.default_rng(3))
    again = optics.image(plain, ranges, np.random.default_rng(3))
    other = optics.image(plain, ranges, np.random.default_rng(4))
    assert np.array_equal(first, again) and not np.array_equal(first, other)
    snow = {
        name: (
            Optics(WATER_TYPES[name], cameras.intrinsics("cam_left"), lamps_of(model, "cam_left")).snow(
                ranges, np.random.default_rng(0)
            )
            > 0.01
        ).sum()
        for name in ("I", "9C")
    }
    assert snow["9C"] > 3 * snow["I"] > 0, snow


def test_the_depth_camera_is_left_alone_and_the_rgb_is_not(
    world: tuple[mujoco.MjModel, mujoco.MjData, Cameras],
) -> None:
    model, data, plain = world
    look_at_marker(model, data, 2.0)
    murky = Cameras(
        model, WIDTH_PX, HEIGHT_PX, water="9C", rng=np.random.default_rng(0), depth_camera=ROBOT.depth_camera
    )
    try:
        assert np.array_equal(murky.depth_m(data, "cam_depth"), plain.depth_m(data, "cam_depth"))
        assert not np.array_equal(murky.rgb(data, "cam_left"), plain.rgb(data, "cam_left"))
    finally:
        murky.close()
