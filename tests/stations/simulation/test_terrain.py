"""Terrain by surface reconstruction: cloud -> Open3D surface -> MuJoCo height field."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest

from abyss.description.robot import robot_at
from abyss.description.site import site_at, world_model
from abyss.stations.simulation import terrain

ROBOT = robot_at("")  # the shipped robot package
SITE = site_at("")  # the shipped site


ROOT = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="module")
def built() -> terrain.Terrain:
    return terrain.reconstruct(terrain.read_cloud(SITE.seabed_cloud_file))


def test_the_shipped_cloud_is_the_seeded_fractal() -> None:
    np.testing.assert_allclose(
        terrain.read_cloud(SITE.seabed_cloud_file), terrain.fractal_cloud(0), atol=1e-9
    )


def test_reconstruction_follows_the_cloud(built: terrain.Terrain) -> None:
    cloud = terrain.read_cloud(SITE.seabed_cloud_file)
    inner = np.all(np.abs(cloud[:, :2]) < terrain.HALF_SIZE_M - 1.0, axis=1)
    error_m = np.abs(terrain.bilinear(built.heights_m, cloud[inner, :2]) - cloud[inner, 2])
    assert np.median(error_m) < 0.05 and np.percentile(error_m, 95) < 0.15  # measured 0.03, 0.09


def test_the_shipped_terrain_is_what_the_tool_builds(built: terrain.Terrain) -> None:
    shipped = terrain.read_hfield(SITE.directory / "terrain.bin")
    assert np.median(np.abs(shipped - built.heights_m)) < 0.01


def test_mujoco_sees_the_terrain_where_the_heights_say(built: terrain.Terrain) -> None:
    model = world_model(ROBOT, SITE)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    heights = terrain.read_hfield(SITE.directory / "terrain.bin")
    seabed = model.geom("seabed").id
    rng = np.random.default_rng(3)
    for x, y in rng.uniform(-15, 15, size=(20, 2)):
        geomid = np.array([-1], dtype=np.int32)
        top = np.array([x, y, 0.0])
        distance = mujoco.mj_ray(model, data, top, np.array([0.0, 0.0, -1.0]), None, 1, -1, geomid)
        if geomid[0] != seabed:
            continue  # the panel or the vehicle is in the way
        expected = terrain.bilinear(heights, np.array([[x, y]]))[0]
        assert -distance == pytest.approx(expected, abs=0.03)


def test_hfield_round_trip(tmp_path: Path) -> None:
    heights = terrain.fractal_heights(5, n=17)
    terrain.write_hfield(heights, tmp_path / "t.bin")
    np.testing.assert_allclose(terrain.read_hfield(tmp_path / "t.bin"), heights, atol=1e-5)


def test_cli_builds_into_a_directory_and_refuses_a_missing_cloud(tmp_path: Path) -> None:
    cloud = tmp_path / "cloud.ply"
    run = [sys.executable, "-m", "abyss.cli", "terrain"]
    subprocess.run([*run, "cloud", str(cloud), "--seed", "3", "--points", "5000"], cwd=ROOT, check=True)
    done = subprocess.run(
        [*run, "build", str(cloud), "--out", str(tmp_path / "t")],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "t" / "terrain.bin").exists() and '<hfield name="terrain"' in done.stdout
    missing = subprocess.run(
        [*run, "build", str(tmp_path / "none.ply")], cwd=ROOT, capture_output=True, text=True, timeout=60
    )
    assert missing.returncode == 2 and "no such file" in missing.stderr
