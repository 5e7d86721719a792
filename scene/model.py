"""The vessel's scene model: an OctoMap occupancy octree with a colour per voxel, integrated from
the onboard clouds by ray casting (free space along each ray, occupied at its end), and what of
it shore has.

The vessel keeps the max-likelihood state of every cell it has published; at most once per track
period it compares the cells in the bounding box of the clouds inserted since (read from the
tree's serialisation: `octree.iterate_leaves`), queues those that changed (occupancy flipped, or
colour moved by more than COLOR_TOLERANCE), and hands the queue out in updates of at most
`max_update_bytes`, each a small octree written with `OcTree::writeBinary` (which prunes), so
that a snapshot too is a first update and then deltas, and telemetry interleaves.
"""

from __future__ import annotations

import threading
import time

import numpy as np
import pyoctomap

from abyss.interface.clouds import voxel_downsample
from abyss.interface.messages import SceneUpdate, new_id, wire_bytes
from abyss.scene.cells import CellSet, moved
from abyss.scene.octree import (
    COLOR_STEP,
    GREY,
    HYSTERESIS_LOG_ODDS,
    Leaves,
    iterate_leaves,
    leaves_to_cells,
    occupied_leaf_colors,
    read_binary,
    write_cells,
)


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
        if len(points_m_world):
            self.integrate(points_m_world, colors, sensor_m_world)
            self.track(stamp_s)

    def integrate(self, points_m_world: np.ndarray, colors: np.ndarray, sensor_m_world: np.ndarray) -> None:
        """Integrate one cloud (rays from the sensor) into the octree alone: nothing is queued
        for shore before the next `track` (which may run in another thread, never beside it)."""
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
        has no colours). Returns its leaves; BadInput when it is no tree of this resolution."""
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
        changed = ~known | flipped | (was_occupied & state & moved(was_rgb, rgb))
        keys, state, rgb = keys[changed], state[changed], rgb[changed]
        sent = sent.of(changed)
        as_sent = sent.found & (sent.occupied == state) & ~(state & moved(sent.colors, rgb))
        self.pending.remove(keys[as_sent])
        self.pending.merge(keys[~as_sent], state[~as_sent], rgb[~as_sent])

    def backlog_cells(self) -> int:
        """How many cells are queued for shore and not yet sent; with a snapshot due, the whole
        map, which goes again."""
        with self._lock:
            if self.snapshot_due:
                return len(np.union1d(self.pending.keys, self.published.keys))
            return len(self.pending)

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
