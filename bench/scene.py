"""Scene modelling figures, on frames rendered from the default mission's start pose:
- cloud fusion per frame (depth: back-projection + colouring + voxel grid + packing; stereo:
  semi-global matching on top), against the floor of decoding the frame set alone;
- octree insertion per frame at 0.05, 0.1 and 0.2 m, against pyoctomap's bare
  insertPointCloud of the same cloud: one into an empty tree, then four more as the vessel
  takes them (the change tracking shared among them), and whether the trees are the same;
- bytes on the satellite hop per scene update, full and incremental, against the OctoMap `.bt`
  size of the same map.
Run: .venv/bin/python bench/scene.py. Prints figures; asserts nothing."""

from __future__ import annotations

import functools
import time

import numpy as np
import pyoctomap

from abyss.launch.station import single_threaded_native_pools
from abyss.stations.simulation.rendering import choose_gl_backend

choose_gl_backend()
single_threaded_native_pools()  # as a station runs them

from abyss.config.simulation import SimulationConfig  # noqa: E402
from abyss.config.stations import VesselConfig  # noqa: E402
from abyss.description.robot import robot_at  # noqa: E402
from abyss.interface.clouds import unpack_cloud, voxel_downsample  # noqa: E402
from abyss.interface.images import decode_image  # noqa: E402
from abyss.interface.messages import encode  # noqa: E402
from abyss.scene.model import SceneModel  # noqa: E402
from abyss.scene.octree import iterate_leaves  # noqa: E402
from abyss.stations.onboard.perception import CloudSettings, clouds_of  # noqa: E402
from abyss.stations.simulation.encoding import encode_image  # noqa: E402
from abyss.stations.simulation.rendering import Cameras  # noqa: E402
from abyss.stations.simulation.world import World  # noqa: E402

ROBOT = robot_at("")  # the shipped robot package

REPEATS = 5


def timed(action, repeats: int = REPEATS) -> float:  # type: ignore[no-untyped-def]
    action()
    t0 = time.perf_counter()
    for _ in range(repeats):
        action()
    return (time.perf_counter() - t0) / repeats


def frames_at(position: tuple[float, float, float]) -> tuple[dict, tuple[np.ndarray, np.ndarray]]:  # type: ignore[type-arg]
    world = World(SimulationConfig(start_position_m_world=position), np.random.default_rng(0))
    cameras = Cameras(world.model, 640, 480, depth_camera=ROBOT.depth_camera)
    frames = {c: encode_image(cameras, world.data, c, 90) for c in ROBOT.cameras}
    cameras.close()
    truth = world.truth()
    return frames, (truth.position_m_world, truth.orientation_wxyz_world)


def main() -> None:
    frames, pose = frames_at((0.0, 0.0, -7.0))
    settings = CloudSettings(voxel_m=0.05)
    decode_s = timed(lambda: [decode_image(frames[c]) for c in ROBOT.cameras])
    depth_s = timed(
        lambda: clouds_of(ROBOT.spec.cameras, frames, pose, np.zeros((0, 3)), ("depth",), settings)
    )
    stereo_s = timed(
        lambda: clouds_of(ROBOT.spec.cameras, frames, pose, np.zeros((0, 3)), ("stereo",), settings)
    )
    print(
        f"cloud fusion per frame: decoding the set {decode_s * 1e3:.0f} ms (floor); "
        f"depth {depth_s * 1e3:.0f} ms "
        f"({depth_s / decode_s:.1f}x); stereo {stereo_s * 1e3:.0f} ms ({stereo_s / decode_s:.1f}x)"
    )
    later, later_pose = frames_at((1.5, 0.0, -7.0))
    first = clouds_of(ROBOT.spec.cameras, frames, pose, np.zeros((0, 3)), ("depth",), settings)[0]
    second = clouds_of(ROBOT.spec.cameras, later, later_pose, np.zeros((0, 3)), ("depth",), settings)[0]
    print(f"a depth cloud: {first.count} points, {len(first.data)} bytes on the tether")
    for resolution_m in (0.05, 0.1, 0.2):
        points, colors = unpack_cloud(first)
        # as the vessel does it: the changes looked for once per track period (5 clouds at 1 Hz)
        # over the region they touched, the walk's cost shared among them
        clouds = [(*unpack_cloud(c), c.sensor_m_world) for c in (first, second) * 3][:5]
        downsampled = [(*voxel_downsample(p, c, resolution_m), s) for p, c, s in clouds]

        def bare(
            count: int, resolution_m: float = resolution_m, downsampled: list = downsampled
        ) -> pyoctomap.ColorOcTree:
            tree = pyoctomap.ColorOcTree(resolution_m)
            for ds_points, ds_colors, sensor in downsampled[:count]:
                tree.insertPointCloud(
                    np.ascontiguousarray(ds_points), sensor, max_range=8.0, colors=ds_colors / 255.0
                )
            return tree

        model = SceneModel(resolution_m, 8.0)
        bare_s = timed(functools.partial(bare, 1), 2)
        bare_next_s = (timed(functools.partial(bare, len(clouds)), 2) - bare_s) / (len(clouds) - 1)
        t0 = time.perf_counter()
        model.insert(points, colors, first.sensor_m_world)
        insert_s = time.perf_counter() - t0
        vessel = SceneModel(resolution_m, 8.0, track_period_s=VesselConfig().scene_track_period_s)
        vessel.insert(*clouds[0], stamp_s=0.0)  # the first walk: nothing is tracked yet
        t0 = time.perf_counter()
        for i, cloud in enumerate(clouds[1:], start=1):
            vessel.insert(*cloud, stamp_s=float(i))
        vessel.track(stamp_s=float(len(clouds)))
        amortised_s = (time.perf_counter() - t0) / (len(clouds) - 1)
        # the vessel's tree against pyoctomap's plain insertion of the same clouds
        ours, plain = iterate_leaves(vessel.tree, colors=True), iterate_leaves(bare(len(clouds)), colors=True)
        same = (
            len(ours.occupied) == len(plain.occupied)
            and np.array_equal(ours.centres_m, plain.centres_m)
            and np.array_equal(ours.log_odds, plain.log_odds)
        )
        recoloured = (
            np.any(ours.colors[ours.occupied] != plain.colors[plain.occupied], axis=1).mean()
            if same
            else float("nan")
        )
        full = []
        while (u := model.next_update(0.0)) is not None:
            full.append(len(encode(u, 0, 0.0)))
        model.insert(*unpack_cloud(second), second.sensor_m_world)
        delta = []
        while (u := model.next_update(0.0)) is not None:
            delta.append(len(encode(u, 0, 0.0)))
        bt = len(model.binary())
        print(
            f"octree {resolution_m:g} m: insertion {insert_s * 1e3:.0f} ms per frame vs bare pyoctomap "
            f"{bare_s * 1e3:.0f} ms ({insert_s / bare_s:.2f}x); the next clouds {amortised_s * 1e3:.0f} ms "
            f"vs {bare_next_s * 1e3:.0f} ms ({amortised_s / bare_next_s:.2f}x) with the vessel's "
            f"{vessel.track_period_s:g} s tracking, the same leaves and log-odds as bare: {same}, "
            f"occupied leaves coloured otherwise {100 * recoloured:.1f} %; "
            f"first map {sum(full)} B in {len(full)} updates, "
            f"next frame {sum(delta)} B in {len(delta)} updates; whole map as .bt {bt} B "
            f"(first map / .bt {sum(full) / bt:.2f}, delta / .bt {sum(delta) / bt:.2f})"
        )
        walk_s = timed(functools.partial(walk_leaves, vessel.tree), 2)
        read_s = timed(functools.partial(iterate_leaves, vessel.tree), 2)
        print(
            f"  its {len(ours.sizes_m)} leaves read: pyoctomap's leaf iterator {walk_s * 1e3:.0f} ms, "
            f"from the serialisation {read_s * 1e3:.0f} ms ({read_s / walk_s:.2f}x)"
        )


def walk_leaves(tree: pyoctomap.ColorOcTree) -> list[tuple]:
    """The leaves through pyoctomap's iterator, leaf by leaf (what iterate_leaves does instead)."""
    return [
        (leaf.getCoordinate(), leaf.getSize(), leaf.current_node.getLogOdds(), leaf.getColor())
        for leaf in tree.begin_leafs()
    ]


if __name__ == "__main__":
    main()
