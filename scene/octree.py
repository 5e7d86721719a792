"""The octree itself, as the scene stream carries it: OctoMap's occupancy octree read and written
in OctoMap's binary format, and its cells (voxels of the finest depth) identified by OctoMap's
key (16 bits per axis) packed into an int64. The vessel's model (`model.SceneModel`) queues the
cells that changed, the stream (`stream.SceneStream`) sends them, shore's copy
(`receiver.SceneReceiver`) applies them. Reading leaves goes through the tree's serialisation in
numpy (`iterate_leaves`), not pyoctomap's iterators.

A bad tree from outside (bytes that do not decode, another resolution) raises `BadInput`.
"""

from __future__ import annotations

import os
import tempfile
from typing import NamedTuple

import numpy as np
import pyoctomap

from abyss.common.errors import BadInput

KEY_OFFSET = 32768  # OctoMap's tree_max_val at depth 16
GREY = 136  # the colour of a cell whose map gives none (the middle of a COLOR_STEP)
COLOR_TOLERANCE = 24  # a colour change larger than this in any channel is sent
COLOR_STEP = 16  # colours go as the middle of steps this wide: 4 bits a channel, well inside the tolerance
# a published cell is sent again only when its log-odds lie this far past the threshold on the
# other side (about two hits of OctoMap's sensor model after a miss, five misses after a hit):
# the cells that stereo noise flips back and forth stay as they were sent
HYSTERESIS_LOG_ODDS = 1.0
LOG_ODDS_SET = 100.0  # applied as an update, clamped: sets a cell occupied (+) or free (-)
_AXIS = np.int64(1 << 16)


def cell_keys(coords_m: np.ndarray, resolution_m: float) -> np.ndarray:
    """The packed key of the cell holding each point."""
    k = np.floor(coords_m / resolution_m).astype(np.int64) + KEY_OFFSET
    return (k[:, 0] * _AXIS + k[:, 1]) * _AXIS + k[:, 2]


def cell_centres(keys: np.ndarray, resolution_m: float) -> np.ndarray:
    k = np.stack((keys // (_AXIS * _AXIS), (keys // _AXIS) % _AXIS, keys % _AXIS), axis=1)
    return (k - KEY_OFFSET + 0.5) * resolution_m


def _spread_bits(axis: np.ndarray) -> np.ndarray:
    """16-bit integers with two zero bits after each bit (the Morton code's part of one axis)."""
    x = axis & 0xFFFF
    for shift, mask in ((16, 0x0000FF0000FF), (8, 0x00F00F00F00F), (4, 0x0C30C30C30C3), (2, 0x249249249249)):
        x = (x | (x << shift)) & mask
    return x


def morton(keys: np.ndarray) -> np.ndarray:
    """The Z-order (Morton) code of packed keys: cells close in it share octree branches, so a run
    of cells in this order writes as a compact subtree."""
    x, y, z = keys // (_AXIS * _AXIS), (keys // _AXIS) % _AXIS, keys % _AXIS
    return (_spread_bits(x) << 2) | (_spread_bits(y) << 1) | _spread_bits(z)


def leaves_to_cells(
    centres_m: np.ndarray, sizes_m: np.ndarray, resolution_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """Expand leaves (centres, edge lengths) into the keys of their cells, and for each cell
    the index of its leaf."""
    keys, owners = [], []
    sides = np.rint(sizes_m / resolution_m).astype(np.int64)
    for side in np.unique(sides):
        chosen = np.nonzero(sides == side)[0]
        corner = np.rint((centres_m[chosen] - sizes_m[chosen, None] / 2) / resolution_m).astype(np.int64)
        steps = np.stack(np.meshgrid(*[np.arange(side)] * 3, indexing="ij"), -1).reshape(-1, 3)
        k = (corner[:, None, :] + steps[None] + KEY_OFFSET).reshape(-1, 3)
        keys.append((k[:, 0] * _AXIS + k[:, 1]) * _AXIS + k[:, 2])
        owners.append(np.repeat(chosen, len(steps)))
    if not keys:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(keys), np.concatenate(owners)


class Leaves(NamedTuple):
    """A tree's leaves in its iteration order."""

    centres_m: np.ndarray
    sizes_m: np.ndarray
    occupied: np.ndarray
    colors: np.ndarray  # RGB; empty unless asked for
    log_odds: np.ndarray  # past the occupancy threshold: positive occupied


# a node as OctoMap's full format (`write`, .ot) holds it, depth first: its value, then which of
# its eight children exist (bit i: child i, whose key has bit x = i & 1, y = i & 2, z = i & 4)
_NODE_OF_TREE = {
    "OcTree": np.dtype([("log_odds", "<f4"), ("children", "u1")]),
    "ColorOcTree": np.dtype([("log_odds", "<f4"), ("rgb", "u1", 3), ("children", "u1")]),
}
_TREE_DEPTH = 16
_CHILD_COUNT = np.array([bin(m).count("1") for m in range(256)], np.int64)
_NTH_CHILD = np.array([([i for i in range(8) if m >> i & 1] + [0] * 8)[:8] for m in range(256)], np.int64)
_CHILD_CORNER = np.array([[i & 1, i >> 1 & 1, i >> 2 & 1] for i in range(8)], np.int64)


def iterate_leaves(
    tree: object, bbx: tuple[np.ndarray, np.ndarray] | None = None, colors: bool = False
) -> Leaves:
    """The leaves of an OcTree or ColorOcTree in OctoMap's iteration order (depth first), or of
    those that overlap `bbx` (low and high corners [m], as OctoMap's box iterator takes them).
    Read from the tree's full serialisation in numpy rather than leaf by leaf through pyoctomap's
    iterators, whose calls cost 4-7x as much as this (bench/scene.py); `colors`: RGB (ColorOcTree)."""
    data = bytes(tree.write())  # type: ignore[attr-defined]
    header, _, body = data.partition(b"\ndata\n")
    fields = dict(line.split(" ", 1) for line in header.decode().splitlines() if line and line[0] != "#")
    node = _NODE_OF_TREE[fields["id"]]
    nodes = np.frombuffer(body, node, count=int(fields["size"]))
    centres_m, sizes_m, chosen = _leaf_boxes(nodes["children"], tree.getResolution(), bbx)  # type: ignore[attr-defined]
    past_threshold = nodes["log_odds"][chosen].astype(float) - tree.getOccupancyThresLog()  # type: ignore[attr-defined]
    rgb = nodes["rgb"][chosen] if colors and "rgb" in (node.names or ()) else np.zeros((0, 3), np.uint8)
    return Leaves(centres_m, sizes_m, past_threshold >= 0.0, rgb, past_threshold)  # >= 0: isNodeOccupied


def _leaf_boxes(
    children: np.ndarray,
    resolution_m: float,
    bbx: tuple[np.ndarray, np.ndarray] | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The centres and edge lengths [m] of the leaves of a tree given as each node's children in
    depth-first order, and the nodes they are (those overlapping `bbx`)."""
    count = len(children)
    if count == 0:
        return np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.int64)
    order = np.arange(count)
    # a node's subtree ends where the subtrees still to be read first drop below those before it
    # (each node reads one and announces its children): the first later position one lower
    pending = np.zeros(count + 1, np.int64)
    np.cumsum(_CHILD_COUNT[children] - 1, out=pending[1:])
    by_pending = np.argsort(pending, kind="stable")
    ends = by_pending[
        np.searchsorted(
            pending[by_pending] * (count + 1) + by_pending, (pending[:count] - 1) * (count + 1) + order + 1
        )
    ]
    depth = order - np.searchsorted(np.sort(ends), order, "right")  # the subtrees it lies in
    # a node's parent: the last node before it one level up; its rank among its siblings
    by_depth = np.argsort(depth, kind="stable")
    parent = np.zeros(count, np.int64)
    above = np.searchsorted(depth[by_depth] * count + by_depth, (depth[1:] - 1) * count + order[1:]) - 1
    parent[1:] = by_depth[above]
    by_parent = np.argsort(parent[1:], kind="stable") + 1
    rank = np.zeros(count, np.int64)
    rank[by_parent] = np.arange(count - 1) - np.searchsorted(parent[by_parent], parent[by_parent])
    child = _NTH_CHILD[children[parent], rank]
    # each node's lowest cell (key), level by level from the root (the key space's corner)
    corner = np.zeros((count, 3), np.int64)
    levels = np.searchsorted(depth[by_depth], np.arange(_TREE_DEPTH + 2))
    for level in range(1, _TREE_DEPTH + 1):
        at = by_depth[levels[level] : levels[level + 1]]
        corner[at] = corner[parent[at]] + _CHILD_CORNER[child[at]] * (1 << (_TREE_DEPTH - level))
    chosen = np.nonzero(children == 0)[0]
    side = 1 << (_TREE_DEPTH - depth[chosen])  # [cells]
    if bbx is not None:
        # OctoMap's keys of the corners: single-precision coordinates times 1 / resolution, floored
        low, high = (
            np.floor(np.asarray(b, np.float32).astype(float) * (1.0 / resolution_m)).astype(np.int64)
            + KEY_OFFSET
            for b in bbx
        )
        leaf_corner = corner[chosen]
        # as OctoMap's box iterator tests a node (its centre key +/- half its side): a leaf larger
        # than a cell reaches one cell past its high side
        reach = np.where(side > 1, side, 0)
        inside = np.all((leaf_corner <= high) & (leaf_corner + reach[:, None] >= low), axis=1)
        chosen, side = chosen[inside], side[inside]
    centres_m = (corner[chosen] + side[:, None] / 2 - KEY_OFFSET) * resolution_m
    return centres_m, side * resolution_m, chosen


def write_cells(keys: np.ndarray, occupied: np.ndarray, resolution_m: float) -> bytes:
    """Cells as an octree in OctoMap's binary format (max likelihood, pruned)."""
    tree = pyoctomap.OcTree(resolution_m)
    centres = cell_centres(keys, resolution_m)
    tree.updateNodes(centres[occupied], LOG_ODDS_SET, True)
    tree.updateNodes(centres[~occupied], -LOG_ODDS_SET, True)
    tree.updateInnerOccupancy()
    return bytes(tree.writeBinary())


def read_binary(data: bytes, resolution_m: float) -> object:
    """An OcTree from OctoMap's binary format (pyoctomap reads only files); BadInput when the
    bytes are no tree, or one of another resolution [m]."""
    tree = pyoctomap.OcTree(resolution_m)
    fd, path = tempfile.mkstemp(suffix=".bt")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        if not tree.readBinary(path):
            raise BadInput("not an OctoMap binary tree")
    finally:
        os.unlink(path)
    if abs(tree.getResolution() - resolution_m) > 1e-9:
        raise BadInput(f"tree resolution {tree.getResolution()} m, the update says {resolution_m} m")
    return tree


def occupied_leaf_colors(
    tree: object, resolution_m: float, color_of_cell: dict[int, tuple[int, int, int]]
) -> np.ndarray:
    """The colours of a tree's occupied leaves in iteration order; a leaf larger than a cell
    takes the colour of its first cell."""
    centres, sizes, occupied = iterate_leaves(tree)[:3]
    first = cell_keys(centres[occupied] - sizes[occupied, None] / 2 + resolution_m / 2, resolution_m)
    return np.array([color_of_cell[int(k)] for k in first], np.uint8).reshape(-1, 3)
