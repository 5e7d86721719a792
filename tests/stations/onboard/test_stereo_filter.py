"""The stereo matcher's filters (perception.StereoFilter): the scene model built from stereo
clouds along the start of the default mission in oceanic water (type I: noise and marine snow
in open water), against the cameras' depth renders, with bench/perception.py's measure; at
half resolution (onboard.stereo_scale); and their settings' validation."""

from __future__ import annotations

import functools
import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from abyss.common.config import OnboardConfig
from abyss.common.errors import ConfigError
from abyss.stations.onboard.perception import Camera, StereoFilter, stereo_depth

BENCH = Path(__file__).parents[3] / "bench" / "perception.py"
PRECISION_FLOOR = 0.42  # measured on 3 frames, seeds 0 and 1: filtered 0.51, 0.48; unfiltered 0.28, 0.29


@functools.cache
def bench() -> ModuleType:
    spec = importlib.util.spec_from_file_location("bench_perception", BENCH)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look their module up
    spec.loader.exec_module(module)
    return module


@pytest.mark.timeout(180)
def test_filtered_stereo_keeps_open_water_empty_in_oceanic_water() -> None:
    filtered = bench().measure(StereoFilter(), "I", frames=3)
    unfiltered = bench().measure(bench().UNFILTERED, "I", frames=3)
    assert filtered.precision > PRECISION_FLOOR, filtered
    assert unfiltered.precision < PRECISION_FLOOR, unfiltered  # the floor tells the filters apart
    assert filtered.recall > 0.15, filtered  # the seabed and the panel are still there


@pytest.mark.parametrize("scale", [1, 2])
def test_a_textureless_pair_gives_no_depth(scale: int) -> None:
    rng = np.random.default_rng(0)
    noise = rng.normal(40, 4, (120, 160, 3)).clip(0, 255).astype(np.uint8)  # dark water, sensor noise
    other = rng.normal(40, 4, (120, 160, 3)).clip(0, 255).astype(np.uint8)
    unfiltered = bench().UNFILTERED
    filtered_m = stereo_depth(noise, other, 100.0, 0.12, 32, 9, StereoFilter(), scale=scale)
    assert filtered_m.shape == (120 // scale, 160 // scale)
    assert (filtered_m > 0).mean() < 0.01
    assert (stereo_depth(noise, other, 100.0, 0.12, 32, 9, unfiltered, scale=scale) > 0).mean() > 0.05


def test_a_shrunk_camera_sees_a_point_where_the_shrunk_image_has_it() -> None:
    camera = Camera(np.array([[400.0, 0.0, 320.0], [0.0, 400.0, 240.0], [0.0, 0.0, 1.0]]), 640, 480,
                    np.eye(3), np.zeros(3))
    half = camera.scaled(2)
    point_m = np.array([0.3, -0.2, 4.0])
    full_px, half_px = (c.matrix @ point_m / point_m[2] for c in (camera, half))
    # a shrunk pixel is the mean of a 2 x 2 block: its centre is at the block's
    np.testing.assert_allclose(2 * half_px[:2] + 0.5, full_px[:2])
    assert (half.width_px, half.height_px) == (320, 240)


@pytest.mark.parametrize("field, value", [("stereo_min_texture", -1.0), ("stereo_uniqueness_percent", 101),
                                          ("stereo_speckle_range_px", 0), ("stereo_edge_step_px", -0.5),
                                          ("stereo_scale", 3)])
def test_stereo_settings_are_validated_with_the_field_named(field: str, value: float) -> None:
    with pytest.raises(ConfigError, match=f"onboard.{field}"):
        OnboardConfig(**{field: value})


def test_the_filters_can_be_switched_off() -> None:
    off = StereoFilter.of(OnboardConfig(stereo_lr_max_diff_px=0, stereo_min_texture=0, stereo_edge_step_px=0))
    assert (off.lr_max_diff_px, off.min_texture, off.edge_step_px) == (0, 0, 0)
