"""Point clouds: voxel downsampling, and the quantised, compressed form they travel in."""

from __future__ import annotations

import zlib

import numpy as np

from abyss.interface.messages import CLOUD_POINT_BYTES, PointCloud

_RECORD = np.dtype([("xyz", "<i2", 3), ("rgb", "u1", 3)])
assert _RECORD.itemsize == CLOUD_POINT_BYTES


def voxel_downsample(
    points_m: np.ndarray, colors: np.ndarray, voxel_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """One point per occupied voxel: the mean of its points and of their colours."""
    if len(points_m) == 0:
        return points_m.reshape(0, 3), colors.reshape(0, 3)
    columns = np.ascontiguousarray(points_m.T)  # x, y, z each contiguous: the passes below run along them
    cells = np.floor(columns / voxel_m).astype(np.int64)
    cells -= cells.min(axis=1, keepdims=True)
    if np.any(cells.max(axis=1) >= 1 << 21):
        raise ValueError(f"a cloud spans more than {(1 << 21) * voxel_m:g} m; split it first")
    packed = (cells[0] << 42) | (cells[1] << 21) | cells[2]  # one int64 per voxel
    inverse, counts = _voxels_of(packed)
    sums = np.column_stack(
        [np.bincount(inverse, weights=c, minlength=len(counts)) for c in (*columns, *colors.T)]
    )
    means = sums / counts[:, None]
    return means[:, :3], np.round(means[:, 3:]).astype(np.uint8)


def _voxels_of(packed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """np.unique(packed, return_inverse=True, return_counts=True) less the values: each key's
    index among the sorted distinct keys, and each distinct key's count. By a stable sort, which
    runs through a cloud made from an image's rows (runs of one voxel) several times faster
    than np.unique's."""
    order = np.argsort(packed, kind="stable")
    ordered = packed[order]
    first = np.empty(len(packed), bool)
    first[0] = True
    np.not_equal(ordered[1:], ordered[:-1], out=first[1:])
    inverse = np.empty(len(packed), np.intp)
    inverse[order] = np.cumsum(first) - 1
    return inverse, np.diff(np.append(np.flatnonzero(first), len(packed)))


def pack_cloud(
    source: str,
    points_m_world: np.ndarray,
    colors: np.ndarray,
    sensor_m_world: np.ndarray,
    scale_m: float,
    sim_time_s: float,
    level: int = 1,
) -> PointCloud:
    """Quantise to `scale_m` from the cloud's centre (int16: +/- 32767 steps) and compress;
    points farther than that from the centre are left out."""
    origin = points_m_world.mean(axis=0) if len(points_m_world) else np.zeros(3)
    steps = np.round((points_m_world - origin) / scale_m)
    keep = np.all(np.abs(steps) <= 32767, axis=1)
    records = np.empty(int(keep.sum()), _RECORD)
    records["xyz"] = steps[keep]
    records["rgb"] = colors[keep]
    return PointCloud(
        source=source,
        count=len(records),
        scale_m=scale_m,
        origin_m_world=origin,
        sensor_m_world=np.asarray(sensor_m_world, float),
        data=zlib.compress(records.tobytes(), level),
        sim_time_s=sim_time_s,
    )


def unpack_cloud(cloud: PointCloud) -> tuple[np.ndarray, np.ndarray]:
    """Points [m, world] (N, 3) and colours uint8 (N, 3); the message was validated on decode."""
    records = np.frombuffer(zlib.decompress(cloud.data), _RECORD)
    return records["xyz"] * cloud.scale_m + cloud.origin_m_world, records["rgb"].copy()
