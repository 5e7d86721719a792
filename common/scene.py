"""The scene model (the vessel's) and its copy (shore's): an OctoMap occupancy octree with a
colour per voxel, integrated from the onboard clouds by ray casting (free space along each ray,
occupied at its end), and the stream that carries it to shore as OctoMap's binary format: one
snapshot, then only what changed.

Change tracking works on cells (voxels of the finest depth) identified by OctoMap's key
(16 bits per axis) packed into an int64. The vessel keeps the max-likelihood state of every
cell it has published; at most once per track period it compares the cells in the bounding box
of the clouds inserted since (read from the tree's serialisation: iterate_leaves), queues those
that changed (occupancy flipped, or colour moved by more than COLOR_TOLERANCE), and publishes
the queue in updates of at most `max_update_bytes`, each a small octree written with
`OcTree::writeBinary` (which prunes), so that a snapshot too is a first update and then deltas,
and telemetry interleaves. Shore applies each update's leaves to its own tree in sequence and
asks for a snapshot after a gap.
"""

from __future__ import annotations

import logging
import os
import tempfile
import threading
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pyoctomap

from abyss.common.clouds import voxel_downsample
from abyss.common.errors import BadInput
from abyss.common.messages import SceneUpdate, new_id, wire_bytes

log = logging.getLogger(__name__)
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
    """An OcTree from OctoMap's binary format (pyoctomap reads only files)."""
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


class Lookup(NamedTuple):
    """Cells looked up in a CellSet: whether each is there, its state and colour."""

    found: np.ndarray
    occupied: np.ndarray
    colors: np.ndarray

    def of(self, chosen: np.ndarray) -> Lookup:
        return Lookup(self.found[chosen], self.occupied[chosen], self.colors[chosen])


def _moved(a_rgb: np.ndarray, b_rgb: np.ndarray) -> np.ndarray:
    """Whether two colours differ past the tolerance, in any channel."""
    return np.any(np.abs(a_rgb.astype(int) - b_rgb) > COLOR_TOLERANCE, axis=1)


class CellSet:
    """Cells by packed key (sorted, unique), each occupied or free, with a colour."""

    def __init__(self) -> None:
        self.keys = np.zeros(0, np.int64)
        self.occupied = np.zeros(0, bool)
        self.colors = np.zeros((0, 3), np.uint8)

    def __len__(self) -> int:
        return len(self.keys)

    def find(self, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Where each key sits, and whether it is there."""
        if not len(self.keys):
            return np.zeros(len(keys), np.int64), np.zeros(len(keys), bool)
        where = np.minimum(np.searchsorted(self.keys, keys), len(self.keys) - 1)
        return where, self.keys[where] == keys

    def merge(self, keys: np.ndarray, occupied: np.ndarray, colors: np.ndarray) -> None:
        """Add or overwrite cells."""
        merged, first = np.unique(np.concatenate((keys, self.keys)), return_index=True)  # new ones first
        self.occupied = np.concatenate((occupied, self.occupied))[first]
        self.colors = np.concatenate((colors, self.colors))[first]
        self.keys = merged

    def lookup(self, keys: np.ndarray) -> Lookup:
        """Each key's state and colour here (free and grey where it is not)."""
        where, found = self.find(keys)
        if not len(self.keys):
            return Lookup(found, found.copy(), np.full((len(keys), 3), GREY, np.uint8))
        return Lookup(found, self.occupied[where] & found, np.where(found[:, None], self.colors[where], GREY))

    def remove(self, keys: np.ndarray) -> None:
        keep = ~np.isin(self.keys, keys, assume_unique=True)
        self.keys, self.occupied, self.colors = self.keys[keep], self.occupied[keep], self.colors[keep]

    def take(self, count: int) -> CellSet:
        """`count` cells, occupied ones first (what the operator needs to see), each kind in Z order
        (a compact region of the octree per update)."""
        chosen = np.sort(np.lexsort((morton(self.keys), ~self.occupied))[:count])
        part = CellSet()
        part.keys, part.occupied, part.colors = self.keys[chosen], self.occupied[chosen], self.colors[chosen]
        return part

    def color_of(self) -> dict[int, tuple[int, int, int]]:
        chosen = np.nonzero(self.occupied)[0]
        return {
            int(k): (int(c[0]), int(c[1]), int(c[2]))
            for k, c in zip(self.keys[chosen], self.colors[chosen], strict=True)
        }


class SceneModel:
    """The vessel's octree, what of it shore has, and what is queued to go. One thread may
    insert while another takes updates: the queue is guarded, the octree is the inserter's."""

    def __init__(
        self,
        resolution_m: float,
        max_range_m: float,
        max_update_bytes: int = 16_000,
        track_period_s: float = 0.0,
    ) -> None:
        self.resolution_m = resolution_m
        # what changed is found by walking the leaves of the region the clouds touched (in Python,
        # the vessel's dearest work): at most once per this period over the union of the regions
        # since, not once per cloud; 0 walks after each cloud. The period runs on the clouds' own
        # stamps, so that the same clouds make the same updates however late they arrive
        self.track_period_s = track_period_s
        self._dirty: tuple[np.ndarray, np.ndarray] | None = None  # the region touched since the last walk
        self._walked_s = -float("inf")  # the stamp of the last walk
        self.max_range_m = max_range_m
        self.max_update_bytes = max_update_bytes
        self.tree = pyoctomap.ColorOcTree(resolution_m)
        self.published = CellSet()
        self.pending = CellSet()
        self.seq = -1
        self.stream_id = new_id()  # shore tells this model's updates from a previous vessel's
        self.snapshot_due = True
        self._bytes_per_cell = 0.05  # learnt from each update, to size the next
        self._lock = threading.Lock()  # over published, pending, seq, snapshot_due

    def insert(
        self,
        points_m_world: np.ndarray,
        colors: np.ndarray,
        sensor_m_world: np.ndarray,
        stamp_s: float | None = None,
    ) -> None:
        """Integrate one cloud (rays from the sensor) and queue the cells whose state changed
        (`track`, at the cloud's `stamp_s`: its simulated time; else the monotonic clock's now)."""
        if len(points_m_world) == 0:
            return
        points, colors = voxel_downsample(points_m_world, colors, self.resolution_m)
        # lazily: the inner nodes are left for the walk (track), where pyoctomap's plain call updates
        # and collapses them along every ray and then updates them all again
        self.tree.insertPointCloud(
            np.ascontiguousarray(points),
            np.asarray(sensor_m_world, float),
            max_range=self.max_range_m,
            lazy_eval=True,
            colors=colors / 255.0,
        )
        margin = 2 * self.resolution_m
        low = np.minimum(points.min(axis=0), sensor_m_world) - margin
        high = np.maximum(points.max(axis=0), sensor_m_world) + margin
        if self._dirty is not None:
            low, high = np.minimum(low, self._dirty[0]), np.maximum(high, self._dirty[1])
        self._dirty = (low, high)
        self.track(stamp_s)

    def track(self, stamp_s: float | None = None) -> None:
        """Queue the cells whose state changed in the region the clouds touched, if
        `track_period_s` has passed since the last walk by the clouds' stamps (the inserter's
        thread calls it: the octree is its own). The period also batches the stream: the cells a
        few clouds reveal write as one compact delta, where a delta per cloud repeats the
        octree's branches."""
        stamp_s = time.monotonic() if stamp_s is None else stamp_s
        since_s = stamp_s - self._walked_s  # negative: the stamps started again (a new simulation)
        if self._dirty is not None and not 0.0 <= since_s < self.track_period_s:
            self._walk(stamp_s)

    def flush(self) -> None:
        """Queue what the clouds since the last walk changed, now (the last clouds, once no
        more come)."""
        if self._dirty is not None:
            self._walk(self._walked_s)

    def _walk(self, stamp_s: float) -> None:
        bbx, self._dirty, self._walked_s = self._dirty, None, stamp_s
        # the inner nodes updated and like children merged once for the clouds since the last walk:
        # the same leaves and log-odds as pyoctomap's plain insertion of each (bench/scene.py
        # checks it); a merged leaf's colour is its children's mean, where the plain call's leaf
        # takes the last point's in it
        self.tree.updateInnerOccupancy()
        self.tree.prune()
        self._queue_changes(iterate_leaves(self.tree, bbx, colors=True))

    def adopt(self, octree: bytes) -> int:
        """Take a whole map made elsewhere (a ROS 2 node's, OctoMap's binary file) for the model's:
        the cells whose state differs from what shore holds are queued, grey (the binary form
        has no colours). Returns its leaves; ValueError when it is no tree of this resolution."""
        leaves = iterate_leaves(read_binary(octree, self.resolution_m))
        self._queue_changes(leaves._replace(colors=np.full((len(leaves.occupied), 3), GREY, np.uint8)))
        return len(leaves.occupied)

    def _queue_changes(self, leaves: Leaves) -> None:
        keys, owners = leaves_to_cells(leaves.centres_m, leaves.sizes_m, self.resolution_m)  # each once
        rgb = leaves.colors[owners] // COLOR_STEP * COLOR_STEP + COLOR_STEP // 2
        with self._lock:
            self._queue(keys, leaves.log_odds[owners], rgb)

    def _queue(self, keys: np.ndarray, log_odds: np.ndarray, rgb: np.ndarray) -> None:
        """Queue the cells shore should see change: unknown to it, flipped past the hysteresis,
        or occupied with a colour moved past the tolerance. Each is judged against the state last
        decided for it, queued or sent, so that when an update went out changes nothing (a cell
        sent free after one miss, then hit once before the next walk, stays free however the
        link paced the updates); one decided back to what shore holds leaves the queue."""
        state = log_odds >= 0.0
        queued, sent = self.pending.lookup(keys), self.published.lookup(keys)
        known = queued.found | sent.found
        was_occupied = np.where(queued.found, queued.occupied, sent.occupied)
        was_rgb = np.where(queued.found[:, None], queued.colors, sent.colors)
        flipped = np.where(was_occupied, log_odds < -HYSTERESIS_LOG_ODDS, log_odds > HYSTERESIS_LOG_ODDS)
        changed = ~known | flipped | (was_occupied & state & _moved(was_rgb, rgb))
        keys, state, rgb = keys[changed], state[changed], rgb[changed]
        sent = sent.of(changed)
        as_sent = sent.found & (sent.occupied == state) & ~(state & _moved(sent.colors, rgb))
        self.pending.remove(keys[as_sent])
        self.pending.merge(keys[~as_sent], state[~as_sent], rgb[~as_sent])

    def request_snapshot(self) -> None:
        """Shore lost track: send everything again, starting with a snapshot."""
        with self._lock:
            self.snapshot_due = True

    def next_update(self, sim_time_s: float, max_bytes: int | None = None) -> SceneUpdate | None:
        """The next update to send, at most `max_bytes` (else `max_update_bytes`) on the wire
        (compressed); None if shore is up to date. Occupied cells go before free ones, each in key order."""
        with self._lock:
            return self._next_update(sim_time_s, max_bytes or self.max_update_bytes)

    def _next_update(self, sim_time_s: float, max_bytes: int) -> SceneUpdate | None:
        kind = "delta"
        if self.snapshot_due:
            self.snapshot_due, kind = False, "snapshot"
            pending, self.pending = self.pending, CellSet()
            self.pending.merge(self.published.keys, self.published.occupied, self.published.colors)
            self.pending.merge(pending.keys, pending.occupied, pending.colors)
        elif not len(self.pending):
            return None
        count = max(1, min(len(self.pending), int(max_bytes / self._bytes_per_cell)))
        while True:
            part = self.pending.take(count)
            update = self._update(kind, part, sim_time_s)
            size = wire_bytes(update)
            self._bytes_per_cell = max(size / max(count, 1), 1e-3)
            if size <= max_bytes or count == 1:
                break
            count = max(1, min(count // 2, int(max_bytes / self._bytes_per_cell)))
        self.pending.remove(part.keys)
        self.published.merge(part.keys, part.occupied, part.colors)
        self.seq += 1
        return update

    def _update(self, kind: str, cells: CellSet, sim_time_s: float) -> SceneUpdate:
        data = write_cells(cells.keys, cells.occupied, self.resolution_m)
        colors = occupied_leaf_colors(
            read_binary(data, self.resolution_m), self.resolution_m, cells.color_of()
        )
        return SceneUpdate(
            kind=kind,
            scene_seq=self.seq + 1,
            resolution_m=self.resolution_m,
            octree=data,
            colors=colors,
            sim_time_s=sim_time_s,
            stream_id=self.stream_id,
        )

    def binary(self) -> bytes:
        """The whole published map in OctoMap's binary format (what shore must hold)."""
        with self._lock:
            return write_cells(self.published.keys, self.published.occupied, self.resolution_m)


class SceneReceiver:
    """Shore's copy: applies updates in sequence; a gap leaves it waiting for a snapshot. The
    updates of a new stream (a restarted vessel's new model) go onto the map shore holds:
    what the vessel saw before its restart stays on shore."""

    def __init__(self) -> None:
        self.tree: object | None = None
        self.resolution_m = 0.0
        self.colors: dict[int, tuple[int, int, int]] = {}  # occupied cell -> RGB
        self.last_seq = -1
        self.applied = 0
        self.gaps = 0
        self.stream_id: int | None = None
        self.new_streams = 0  # streams that followed another (vessel restarts)
        self.latest_centres_m = np.zeros((0, 3))  # the occupied cells of the latest update applied
        self.latest_colors = np.zeros((0, 3), np.uint8)

    def apply(self, update: SceneUpdate) -> str:
        """'applied', or 'gap' (a snapshot is needed; nothing applied) or 'stale' (old update).
        Raises ValueError if the octree bytes do not decode."""
        merge = False  # a new stream's first update, onto the map held
        if update.stream_id != self.stream_id:
            merge = self.tree is not None and update.scene_seq == 0  # else its start was lost: a gap
            self.new_streams += merge
            self.last_seq = -1  # the new stream's sequence numbers start again
            self.stream_id = update.stream_id
        if update.kind == "delta":
            if self.tree is None or update.scene_seq > self.last_seq + 1:
                self.gaps += self.tree is not None
                self.tree = None  # wait for the snapshot: applying past a gap would corrupt the map
                return "gap"
            if update.scene_seq <= self.last_seq:
                return "stale"
        delta = read_binary(update.octree, update.resolution_m)
        centres, sizes, occupied = iterate_leaves(delta)[:3]
        if int(occupied.sum()) != len(update.colors):
            raise ValueError(f"{len(update.colors)} colours for {int(occupied.sum())} occupied leaves")
        if update.kind == "snapshot" and not merge:
            self.tree, self.resolution_m, self.colors = (
                pyoctomap.OcTree(update.resolution_m),
                update.resolution_m,
                {},
            )
        elif abs(update.resolution_m - self.resolution_m) > 1e-9:
            raise ValueError(f"a delta at {update.resolution_m} m onto a map at {self.resolution_m} m")
        keys, owners = leaves_to_cells(centres, sizes, self.resolution_m)
        cell_occupied = occupied[owners]
        centres_of_cells = cell_centres(keys, self.resolution_m)
        self.tree.updateNodes(centres_of_cells[cell_occupied], LOG_ODDS_SET, True)  # type: ignore[union-attr]
        self.tree.updateNodes(centres_of_cells[~cell_occupied], -LOG_ODDS_SET, True)  # type: ignore[union-attr]
        self.tree.updateInnerOccupancy()  # type: ignore[union-attr]
        color_of_leaf = np.zeros((len(occupied), 3), np.uint8)
        color_of_leaf[occupied] = update.colors
        for key, occ, owner in zip(keys, cell_occupied, owners, strict=True):
            if occ:
                self.colors[int(key)] = tuple(int(c) for c in color_of_leaf[owner])  # type: ignore[assignment]
            else:
                self.colors.pop(int(key), None)
        self.latest_centres_m = centres_of_cells[cell_occupied]
        self.latest_colors = color_of_leaf[owners[cell_occupied]]
        self.last_seq = update.scene_seq
        self.applied += 1
        return "applied"

    def binary(self) -> bytes:
        """Shore's map in OctoMap's binary format."""
        if self.tree is None:
            return b""
        return bytes(self.tree.writeBinary())  # type: ignore[attr-defined]

    def occupied_cells(self) -> tuple[np.ndarray, np.ndarray]:
        """Centres [m] and colours of the occupied cells."""
        keys = np.array(sorted(self.colors), np.int64)
        colors = np.array([self.colors[int(k)] for k in keys], np.uint8).reshape(-1, 3)
        return cell_centres(keys, self.resolution_m), colors

    def snapshot(self, sim_time_s: float = 0.0) -> SceneUpdate | None:
        """The whole map as one snapshot update (what a run keeps; `abyss scene export` reads
        it back); None before the first update."""
        if self.tree is None:
            return None
        data = self.binary()
        colors = occupied_leaf_colors(read_binary(data, self.resolution_m), self.resolution_m, self.colors)
        return SceneUpdate(
            kind="snapshot",
            scene_seq=max(self.last_seq, 0),
            resolution_m=self.resolution_m,
            octree=data,
            colors=colors,
            sim_time_s=sim_time_s,
        )


def occupied_leaf_colors(
    tree: object, resolution_m: float, color_of_cell: dict[int, tuple[int, int, int]]
) -> np.ndarray:
    """The colours of a tree's occupied leaves in iteration order; a leaf larger than a cell
    takes the colour of its first cell."""
    centres, sizes, occupied = iterate_leaves(tree)[:3]
    first = cell_keys(centres[occupied] - sizes[occupied, None] / 2 + resolution_m / 2, resolution_m)
    return np.array([color_of_cell[int(k)] for k in first], np.uint8).reshape(-1, 3)


def export(update: SceneUpdate, path: Path, fmt: str) -> int:
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
