"""Stereo perception over a whole mission: precision and recall of the scene model's occupied
cells against the world's geometry, and the stereo cloud's cost per frame, with the stereo
filters (stereo.StereoFilter) and without them (OpenCV's semi-global matcher as it was),
in clear water (simulation.water "none": MuJoCo's fog) and in Jerlov's oceanic type I
(attenuation, backscatter, marine snow and sensor noise).

The vehicle flies the default mission's path (MissionConfig's waypoints from the start pose,
yaw turning along each leg) at onboard's speed limit, a frame set at each camera period; each
stereo cloud is made by the onboard core (clouds_of) from the true pose and integrated as the
vessel does (SceneModel.insert at its resolution and range). The truth is the left camera's
depth render at the same poses (MuJoCo's depth buffer: a ray cast through every pixel) within
the clouds' range, as cells of the same octree grid. An occupied cell is right when a truth
cell lies within one cell of it (stereo's depth error at 4 m is 4 cm, a cell is 10 cm);
precision: the occupied cells that are right over all occupied cells; recall: the truth cells
with an occupied cell within one cell of them over all truth cells. Strict figures (the same
cell) are printed too.

Run: .venv/bin/python bench/perception.py [frames] [variant ...] (VARIANTS: the filters, the pair
at half resolution or its left-right check's match at full, matching on every second frame set;
by default unfiltered, filtered, full-lr, half). Prints figures; asserts nothing. Also
stereo_depth's cost alone on one pair (the left-right check matches a second time, at half
resolution by default).
tests/stations/onboard/test_stereo_filter.py runs `measure` on a short path."""

from __future__ import annotations

import dataclasses
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from abyss.launch.station import single_threaded_native_pools
from abyss.stations.simulation.rendering import choose_gl_backend

choose_gl_backend()
single_threaded_native_pools()  # as a station runs them

import mujoco  # noqa: E402

from abyss.common.geometry import rotation_of  # noqa: E402
from abyss.config.simulation import SimulationConfig  # noqa: E402
from abyss.config.stations import OnboardConfig, VesselConfig  # noqa: E402
from abyss.config.system import MissionConfig  # noqa: E402
from abyss.description.robot import robot_at  # noqa: E402
from abyss.interface.clouds import unpack_cloud  # noqa: E402
from abyss.scene.model import SceneModel  # noqa: E402
from abyss.scene.octree import cell_keys, iterate_leaves, leaves_to_cells  # noqa: E402
from abyss.stations.onboard.perception import Camera, CloudSettings, clouds_of, depth_to_points  # noqa: E402
from abyss.stations.onboard.stereo import StereoFilter, stereo_depth  # noqa: E402
from abyss.stations.simulation.encoding import encode_image  # noqa: E402
from abyss.stations.simulation.rendering import Cameras  # noqa: E402
from abyss.stations.simulation.world import World  # noqa: E402

ROBOT = robot_at("")  # the shipped robot package

UNFILTERED = StereoFilter(
    uniqueness_ratio=10,
    speckle_window_px=100,
    speckle_range_px=2,
    lr_max_diff_px=0.0,
    min_texture=0.0,
    edge_step_px=0.0,
)  # before the filters
NEIGHBOURS = np.stack(np.meshgrid(*[np.arange(-1, 2)] * 3, indexing="ij"), -1).reshape(-1, 3)


def mission_poses(step_m: float) -> Iterator[tuple[np.ndarray, float]]:
    """Positions [m, world] and yaws [rad] every `step_m` along the default mission's legs."""
    position = np.array(SimulationConfig().start_position_m_world, float)
    yaw_rad = SimulationConfig().start_yaw_rad
    yield position, yaw_rad
    for *goal, goal_yaw_rad in MissionConfig().waypoints:
        length_m = float(np.linalg.norm(np.array(goal) - position))
        steps = max(1, int(np.ceil(length_m / step_m)))
        for i in range(1, steps + 1):
            f = i / steps
            yield position + f * (np.array(goal) - position), yaw_rad + f * (goal_yaw_rad - yaw_rad)
        position, yaw_rad = np.array(goal, float), goal_yaw_rad


@dataclass(frozen=True)
class Figures:
    frames: int
    occupied: int  # cells of the scene model
    truth: int  # cells the cameras' rays hit within range
    precision: float  # occupied cells within one cell of a truth cell, over the occupied
    recall: float  # truth cells within one cell of an occupied cell, over the truth
    strict_precision: float  # the same cell
    strict_recall: float
    stereo_s: float  # [s] the stereo cloud per matched frame set (clouds_of), mean

    def __str__(self) -> str:
        return (
            f"{self.frames} frames: {self.occupied} occupied cells, {self.truth} truth cells; "
            f"precision {self.precision:.3f} (strict {self.strict_precision:.3f}), "
            f"recall {self.recall:.3f} (strict {self.strict_recall:.3f}); "
            f"stereo cloud {self.stereo_s * 1e3:.0f} ms per matched set"
        )


def near(keys: np.ndarray, of: np.ndarray) -> np.ndarray:
    """Whether each cell of `keys` has a cell of `of` within one cell (26-neighbourhood)."""
    axis = np.int64(1 << 16)
    offsets = (NEIGHBOURS[:, 0] * axis + NEIGHBOURS[:, 1]) * axis + NEIGHBOURS[:, 2]
    return np.isin(keys[:, None] + offsets[None, :], of).any(axis=1)


def measure(
    kept: StereoFilter,
    water: str = "none",
    frames: int | None = None,
    step_m: float | None = None,
    seed: int = 0,
    scale: int = 1,
    every: int = 1,
    mode: str = "hh",
) -> Figures:
    """The figures over the first `frames` frame sets (all: None) of the mission's path, a frame
    set every `step_m` (None: onboard's speed limit over the camera period), the pair matched
    `scale` times smaller (onboard.stereo_scale) on every `every`-th set (onboard.stereo_every)."""
    sim, onboard, vessel = SimulationConfig(water=water), OnboardConfig(), VesselConfig()
    step_m = step_m if step_m is not None else onboard.max_speed_mps / sim.camera_rate_hz
    world = World(sim, np.random.default_rng(seed))
    cameras = cameras_of(world, sim, np.random.default_rng(seed))
    settings = dataclasses.replace(
        CloudSettings.of(onboard), stereo_filter=kept, stereo_scale=scale, stereo_mode=mode
    )
    model = SceneModel(vessel.octree_resolution_m, vessel.octree_max_range_m)
    truth: list[np.ndarray] = []
    stereo_s = 0.0
    p = world.plant.qpos
    count = matched = 0
    try:
        for position, yaw_rad in mission_poses(step_m):
            if frames is not None and count >= frames:
                break
            count += 1
            world.data.qpos[p : p + 3] = position
            world.data.qpos[p + 3 : p + 7] = [np.cos(yaw_rad / 2), 0.0, 0.0, np.sin(yaw_rad / 2)]
            mujoco.mj_forward(world.model, world.data)
            images = {c: encode_image(cameras, world.data, c, sim.jpeg_quality) for c in ROBOT.cameras}
            pose = (position, np.array([np.cos(yaw_rad / 2), 0.0, 0.0, np.sin(yaw_rad / 2)]))
            if (count - 1) % every == 0:
                t0 = time.perf_counter()
                cloud = clouds_of(ROBOT.spec.cameras, images, pose, np.zeros((0, 3)), ("stereo",), settings)[
                    0
                ]
                stereo_s += time.perf_counter() - t0
                matched += 1
                model.insert(*unpack_cloud(cloud), cloud.sensor_m_world)
            left = Camera.of(images[ROBOT.stereo_left])
            points, _ = depth_to_points(
                cameras.depth_m(world.data, ROBOT.stereo_left), left, settings.max_range_m
            )
            in_vehicle = points @ left.rotation_in_vehicle.T + left.position_m_vehicle
            truth.append(cell_keys(in_vehicle @ rotation_of(pose[1]).T + position, model.resolution_m))
    finally:
        cameras.close()
    centres, sizes, occupied = iterate_leaves(model.tree)[:3]
    occupied_keys = np.unique(leaves_to_cells(centres[occupied], sizes[occupied], model.resolution_m)[0])
    truth_keys = np.unique(np.concatenate(truth))
    return Figures(
        count,
        len(occupied_keys),
        len(truth_keys),
        float(near(occupied_keys, truth_keys).mean()) if len(occupied_keys) else 0.0,
        float(near(truth_keys, occupied_keys).mean()),
        float(np.isin(occupied_keys, truth_keys).mean()) if len(occupied_keys) else 0.0,
        float(np.isin(truth_keys, occupied_keys).mean()),
        stereo_s / max(matched, 1),
    )


def cameras_of(world: World, sim: SimulationConfig, rng: np.random.Generator | None = None) -> Cameras:
    """The simulation's cameras on `world`, as `sim` sets them (its water, its snow)."""
    return Cameras(
        world.model, sim.camera_width_px, sim.camera_height_px, sim.water, sim.marine_snow, rng,
        depth_camera=ROBOT.depth_camera,
    )  # fmt: skip


def stereo_cost_s(
    kept: StereoFilter, water: str, scale: int = 1, mode: str = "hh", repeats: int = 10
) -> float:
    """[s] stereo_depth alone on the start pose's pair, mean of `repeats` after one."""
    sim = SimulationConfig(water=water)
    world = World(sim, np.random.default_rng(0))
    cameras = cameras_of(world, sim)
    try:
        left, right = cameras.rgb(world.data, ROBOT.stereo_left), cameras.rgb(world.data, ROBOT.stereo_right)
        focal_px = cameras.intrinsics(ROBOT.stereo_left).fx_px
        baseline_m = float(
            np.linalg.norm(
                cameras.pose_in_vehicle(ROBOT.stereo_right)[:3]
                - cameras.pose_in_vehicle(ROBOT.stereo_left)[:3]
            )
        )
    finally:
        cameras.close()
    disparities = OnboardConfig().stereo_disparities
    stereo_depth(left, right, focal_px, baseline_m, disparities, kept=kept, scale=scale, mode=mode)
    t0 = time.perf_counter()
    for _ in range(repeats):
        stereo_depth(left, right, focal_px, baseline_m, disparities, kept=kept, scale=scale, mode=mode)
    return (time.perf_counter() - t0) / repeats


@dataclass(frozen=True)
class Variant:
    kept: StereoFilter
    scale: int = 1  # onboard.stereo_scale
    every: int = 1  # onboard.stereo_every
    mode: str = "hh"  # onboard.stereo_mode


VARIANTS = {
    "unfiltered": Variant(UNFILTERED),
    "filtered": Variant(StereoFilter()),
    "full-lr": Variant(StereoFilter(lr_scale=1)),  # the left-right check's match at full resolution
    "half": Variant(StereoFilter(), scale=2),  # the pair matched at half resolution
    "filtered/2": Variant(StereoFilter(), every=2),  # on every second frame set
    "half/2": Variant(StereoFilter(), scale=2, every=2),
    "hh4": Variant(StereoFilter(), mode="hh4"),  # four directions, not eight
    "sgbm": Variant(StereoFilter(), mode="sgbm"),
}


def main() -> None:
    args = sys.argv[1:]
    frames = int(args.pop(0)) if args and args[0].isdigit() else None
    names = args or ["unfiltered", "filtered", "full-lr", "half"]
    for water in ("none", "I"):
        costs = {
            name: stereo_cost_s(VARIANTS[name].kept, water, VARIANTS[name].scale, VARIANTS[name].mode)
            for name in names
        }
        listed = ", ".join(f"{name} {cost_s * 1e3:.0f} ms" for name, cost_s in costs.items())
        print(f"water {water}: stereo_depth per pair: {listed}", flush=True)
        for name in names:
            v = VARIANTS[name]
            figures = measure(v.kept, water, frames, scale=v.scale, every=v.every, mode=v.mode)
            print(f"water {water}, {name}: {figures}", flush=True)


if __name__ == "__main__":
    main()
