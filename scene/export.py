"""The map a run leaves: shore's final scene as one snapshot update in the run directory
(`SCENE_FILE`), and that snapshot written out as an OctoMap `.bt` file or a coloured `.ply`
cloud (`abyss scene export`)."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from abyss.interface.messages import SceneUpdate, encode
from abyss.scene.receiver import SceneReceiver

SCENE_FILE = "scene.msgpack"  # the final scene, a snapshot SceneUpdate; `abyss scene export` reads it
Format = Literal["bt", "ply"]


def save_snapshot(receiver: SceneReceiver, directory: Path, sim_time_s: float, stamp_s: float) -> bool:
    """Shore's map as one snapshot update (at `sim_time_s`, sent at `stamp_s` [s]) in
    `directory`/SCENE_FILE; False (nothing written) before the first update."""
    snapshot = receiver.snapshot(sim_time_s)
    if snapshot is None:
        return False
    (directory / SCENE_FILE).write_bytes(encode(snapshot, 0, stamp_s))
    return True


def export(update: SceneUpdate, path: Path, fmt: Format) -> int:
    """Write a snapshot as an OctoMap `.bt` file or a coloured `.ply` cloud of the occupied
    cells' centres; returns the number of occupied cells."""
    receiver = SceneReceiver()
    receiver.apply(update)
    centres, colors = receiver.occupied_cells()
    if fmt == "bt":
        path.write_bytes(receiver.binary())
    else:
        import open3d as o3d

        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(centres))
        cloud.colors = o3d.utility.Vector3dVector(colors / 255.0)
        if not o3d.io.write_point_cloud(path, cloud):
            raise OSError(f"Open3D could not write {path}")
    return len(centres)
