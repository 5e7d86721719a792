"""Seabed terrain by surface reconstruction, as the original project made its terrain from
a point cloud recorded at sea: a cloud -> a surface (Open3D's Poisson reconstruction) ->
heights sampled on a grid by ray casting -> a MuJoCo height field (binary .bin: int32 rows,
int32 columns, float32 heights [m], row-major, first row at -y).

A seeded fractal cloud (spectral synthesis, 1/f^2 power, flattened where the panel stands)
stands in for the recorded one."""

from __future__ import annotations

import logging
import re
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from abyss.common.errors import AbyssError

log = logging.getLogger(__name__)

HALF_SIZE_M = 20.0  # the terrain spans [-20, 20] m in x and y
SEABED_Z_M = -10.0  # mean depth of the seabed
GRID = 129  # height samples per side
FLAT_AROUND_M_WORLD = ((5.0, 0.0, 2.5),)  # (x, y, radius): where the panel stands


class TerrainError(AbyssError):
    pass


def fractal_heights(seed: int, n: int = GRID, relief_m: float = 0.8) -> np.ndarray:
    """An n x n fractal surface [m] around the seabed depth, flat where the panel stands."""
    rng = np.random.default_rng(seed)
    fx = np.fft.fftfreq(n)[:, None]
    fy = np.fft.fftfreq(n)[None, :]
    f = np.hypot(fx, fy)
    f[0, 0] = np.inf
    spectrum = (rng.normal(size=(n, n)) + 1j * rng.normal(size=(n, n))) / f  # amplitude 1/f
    heights = np.real(np.fft.ifft2(spectrum))
    heights = relief_m * (heights - heights.mean()) / (heights.max() - heights.min())
    xs = np.linspace(-HALF_SIZE_M, HALF_SIZE_M, n)
    x, y = np.meshgrid(xs, xs, indexing="xy")
    for cx, cy, radius in FLAT_AROUND_M_WORLD:
        weight = np.clip((np.hypot(x - cx, y - cy) - radius) / radius, 0.0, 1.0)
        heights *= weight
    return SEABED_Z_M + heights


def fractal_cloud(seed: int, points: int = 20000, noise_m: float = 0.01) -> np.ndarray:
    """A seabed point cloud (points x 3, world frame [m]) sampled from the fractal surface,
    with sensor noise, as a survey would record it."""
    rng = np.random.default_rng(seed + 1)
    heights = fractal_heights(seed)
    xy = rng.uniform(-HALF_SIZE_M, HALF_SIZE_M, size=(points, 2))
    z = bilinear(heights, xy)
    return np.c_[xy, z + rng.normal(0.0, noise_m, points)]


def bilinear(heights: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Heights at world (x, y) from a grid over [-HALF_SIZE_M, HALF_SIZE_M]^2 (rows: y)."""
    n = heights.shape[0]
    u = (xy[:, 0] + HALF_SIZE_M) / (2 * HALF_SIZE_M) * (n - 1)
    v = (xy[:, 1] + HALF_SIZE_M) / (2 * HALF_SIZE_M) * (n - 1)
    i0 = np.clip(np.floor(v).astype(int), 0, n - 2)
    j0 = np.clip(np.floor(u).astype(int), 0, n - 2)
    a, b = v - i0, u - j0
    return (
        (1 - a) * (1 - b) * heights[i0, j0]
        + (1 - a) * b * heights[i0, j0 + 1]
        + a * (1 - b) * heights[i0 + 1, j0]
        + a * b * heights[i0 + 1, j0 + 1]
    )


@dataclass(frozen=True)
class Terrain:
    heights_m: np.ndarray  # GRID x GRID, rows along y, world frame
    vertices: int
    triangles: int


def reconstruct(points_m: np.ndarray, depth: int = 8) -> Terrain:
    """Poisson surface reconstruction, then the surface's height on the grid by casting rays
    down through it."""
    import open3d as o3d

    if points_m.ndim != 2 or points_m.shape[1] != 3 or len(points_m) < 100:
        raise TerrainError(f"need a cloud of at least 100 points (x, y, z), got shape {points_m.shape}")
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points_m))
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=1.0, max_nn=30))
    cloud.orient_normals_to_align_with_direction(np.array([0.0, 0.0, 1.0]))
    mesh, _ = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(cloud, depth=depth)
    mesh = mesh.crop(cloud.get_axis_aligned_bounding_box())
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    xs = np.linspace(-HALF_SIZE_M, HALF_SIZE_M, GRID)
    x, y = np.meshgrid(xs, xs, indexing="xy")
    top = float(points_m[:, 2].max()) + 10.0
    rays = np.c_[x.ravel(), y.ravel(), np.full(x.size, top), np.zeros((x.size, 2)), -np.ones(x.size)]
    rays_t = o3d.core.Tensor(rays.astype(np.float32), o3d.core.float32, o3d.core.Device("CPU:0"))
    hit = scene.cast_rays(rays_t)["t_hit"].numpy()
    heights = top - hit.reshape(GRID, GRID).astype(float)
    missing = ~np.isfinite(heights)
    if missing.all():
        raise TerrainError("the reconstructed surface covers none of the terrain grid")
    return Terrain(fill_from_neighbours(heights), len(mesh.vertices), len(mesh.triangles))


def fill_from_neighbours(heights: np.ndarray) -> np.ndarray:
    """Cells the surface does not reach (NaN, at the edges) take the mean of their filled
    4-neighbours, growing inwards from the known ones."""
    heights = np.where(np.isfinite(heights), heights, np.nan)  # a ray that missed: t_hit = inf
    while (missing := np.isnan(heights)).any():
        padded = np.pad(heights, 1, constant_values=np.nan)
        neighbours = np.stack([padded[:-2, 1:-1], padded[2:, 1:-1], padded[1:-1, :-2], padded[1:-1, 2:]])
        with warnings.catch_warnings():  # a cell with no filled neighbour yet: NaN, next round
            warnings.simplefilter("ignore", RuntimeWarning)
            fill = np.nanmean(neighbours, axis=0)
        heights[missing & np.isfinite(fill)] = fill[missing & np.isfinite(fill)]
    return heights


def write_hfield(heights_m: np.ndarray, path: Path) -> None:
    rows, cols = heights_m.shape
    with path.open("wb") as f:
        np.array([rows, cols], "<i4").tofile(f)
        heights_m.astype("<f4").tofile(f)


def read_hfield(path: Path) -> np.ndarray:
    raw = path.read_bytes()
    rows, cols = np.frombuffer(raw[:8], "<i4")
    return np.frombuffer(raw[8:], "<f4").reshape(rows, cols).astype(float)


def read_cloud(path: Path) -> np.ndarray:
    import open3d as o3d

    if not path.exists():
        raise TerrainError(f"{path}: no such file")
    points = np.asarray(o3d.io.read_point_cloud(path).points)
    if len(points) == 0:
        raise TerrainError(f"{path}: no points read (a .ply, .pcd or .xyz point cloud is expected)")
    return points


CLOUD_SUFFIXES = (".ply", ".pcd", ".xyz")  # what Open3D writes and `read_cloud` reads back


def write_cloud(points_m: np.ndarray, path: Path) -> None:
    """Write the points to `path`, a point cloud file by its suffix; TerrainError where it cannot."""
    import open3d as o3d

    if path.suffix.lower() not in CLOUD_SUFFIXES:
        raise TerrainError(f"{path}: a point cloud file is named .ply, .pcd or .xyz")
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points_m))
    if not o3d.io.write_point_cloud(path, cloud):
        raise TerrainError(f"{path}: could not be written (does its directory exist?)")


def hfield_xml(heights_m: np.ndarray, file_name: str) -> tuple[str, str]:
    """The MJCF hfield asset and geom for these heights: MuJoCo normalises the file's heights
    to [0, 1], so the elevation range goes into `size` and the lowest point into `pos`."""
    low, high = float(heights_m.min()), float(heights_m.max())
    asset = (
        f'<hfield name="terrain" file="{file_name}" '
        f'size="{HALF_SIZE_M:g} {HALF_SIZE_M:g} {max(high - low, 1e-3):.4f} 0.5"/>'
    )
    geom = f'<geom name="seabed" type="hfield" hfield="terrain" pos="0 0 {low:.4f}" material="seabed"/>'
    return asset, geom


def install(heights_m: np.ndarray, models_dir: Path, world_file: Path) -> None:
    """Write the height field next to the world and point the world's terrain at it."""
    write_hfield(heights_m, models_dir / "terrain.bin")
    asset, geom = hfield_xml(heights_m, "terrain.bin")
    text = world_file.read_text()
    text, n_asset = re.subn(r'<hfield name="terrain"[^>]*/>', asset, text)
    text, n_geom = re.subn(r'<geom name="seabed"[^>]*/>', geom, text)
    if n_asset != 1 or n_geom != 1:
        raise TerrainError(
            f'{world_file}: expected one <hfield name="terrain"> and one '
            f'<geom name="seabed">, found {n_asset} and {n_geom}'
        )
    world_file.write_text(text)
