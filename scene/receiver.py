"""Shore's copy of the scene (`SceneReceiver`: applies the vessel's updates in sequence; a gap
leaves it waiting for a snapshot) and the core around it (`ShoreScene`: acknowledges each
update, applies it, asks for a snapshot when it has no map or missed an update), without Zenoh."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import pyoctomap

from abyss.common.errors import BadInput
from abyss.interface.messages import SceneAck, SceneRequest, SceneUpdate, wire_bytes
from abyss.scene.octree import (
    LOG_ODDS_SET,
    cell_centres,
    iterate_leaves,
    leaves_to_cells,
    occupied_leaf_colors,
    read_binary,
)

log = logging.getLogger(__name__)
Outcome = Literal["applied", "gap", "stale"]


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

    def apply(self, update: SceneUpdate) -> Outcome:
        """'applied', or 'gap' (a snapshot is needed; nothing applied) or 'stale' (old update).
        Raises BadInput if the octree bytes do not decode or do not fit the map."""
        merge = self._follow(update)
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
            raise BadInput(f"{len(update.colors)} colours for {int(occupied.sum())} occupied leaves")
        if update.kind == "snapshot" and not merge:
            self.tree, self.resolution_m, self.colors = (
                pyoctomap.OcTree(update.resolution_m),
                update.resolution_m,
                {},
            )
        elif abs(update.resolution_m - self.resolution_m) > 1e-9:
            raise BadInput(f"a delta at {update.resolution_m} m onto a map at {self.resolution_m} m")
        self._write(centres, sizes, occupied, update.colors)
        self.last_seq = update.scene_seq
        self.applied += 1
        return "applied"

    def _follow(self, update: SceneUpdate) -> bool:
        """Take up `update`'s stream if it is a new one; whether its updates go onto the map held
        (a new stream's first update; else its start was lost: a gap)."""
        if update.stream_id == self.stream_id:
            return False
        merge = self.tree is not None and update.scene_seq == 0
        self.new_streams += merge
        self.last_seq = -1  # the new stream's sequence numbers start again
        self.stream_id = update.stream_id
        return merge

    def _write(
        self, centres_m: np.ndarray, sizes_m: np.ndarray, occupied: np.ndarray, colors: np.ndarray
    ) -> None:
        """An update's leaves (centres and edge lengths [m], occupied or free; the occupied ones'
        colours) onto the map, cell by cell."""
        keys, owners = leaves_to_cells(centres_m, sizes_m, self.resolution_m)
        cell_occupied = occupied[owners]
        centres_of_cells = cell_centres(keys, self.resolution_m)
        tree: object = self.tree
        tree.updateNodes(centres_of_cells[cell_occupied], LOG_ODDS_SET, True)  # type: ignore[attr-defined]
        tree.updateNodes(centres_of_cells[~cell_occupied], -LOG_ODDS_SET, True)  # type: ignore[attr-defined]
        tree.updateInnerOccupancy()  # type: ignore[attr-defined]
        color_of_leaf = np.zeros((len(occupied), 3), np.uint8)
        color_of_leaf[occupied] = colors
        for key, occ, owner in zip(keys, cell_occupied, owners, strict=True):
            if occ:
                self.colors[int(key)] = tuple(int(c) for c in color_of_leaf[owner])  # type: ignore[assignment]
            else:
                self.colors.pop(int(key), None)
        self.latest_centres_m = centres_of_cells[cell_occupied]
        self.latest_colors = color_of_leaf[owners[cell_occupied]]

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


@dataclass
class Applied:
    """An update applied: the occupied cells it set (centres [m, world], RGB) and its sim time [s]."""

    index: int  # in the step's updates
    centres_m_world: np.ndarray
    colors: np.ndarray
    sim_time_s: float


@dataclass
class ShoreSceneOutputs:
    acks: list[SceneAck] = field(default_factory=list)  # one per update, in order: the vessel paces by these
    applied: list[Applied] = field(default_factory=list)
    rejected: list[tuple[int, str]] = field(default_factory=list)  # (index in the step's updates, why)
    request: SceneRequest | None = None  # a snapshot asked for
    new_stream: bool = False  # a new stream went onto the map held (a restarted vessel)


class ShoreScene:
    """Shore's scene stream, without Zenoh: each update acknowledged, then applied in sequence
    onto `receiver`; an update that does not decode counts as a gap. While shore holds no map
    (none yet, or a gap waits for its snapshot) it asks for a snapshot every `request_period_s`,
    and at once after a gap."""

    def __init__(self, request_period_s: float) -> None:
        self.request_period_s = request_period_s
        self.receiver = SceneReceiver()
        self.requests = 0
        self.update_bytes = 0  # on the wire, of the updates applied
        self.sim_time_s = 0.0  # of the latest update applied
        self._last_request_s = -float("inf")

    def step(self, updates: list[SceneUpdate], now_s: float) -> ShoreSceneOutputs:
        out = ShoreSceneOutputs()
        streams = self.receiver.new_streams
        for index, update in enumerate(updates):
            out.acks.append(SceneAck(update.scene_seq))
            try:
                outcome: Outcome = self.receiver.apply(update)
            except BadInput as exc:  # octree bytes that do not decode
                out.rejected.append((index, exc.reason))
                outcome = "gap"
            if outcome == "applied":
                self.update_bytes += wire_bytes(update)
                self.sim_time_s = update.sim_time_s
                r = self.receiver
                out.applied.append(Applied(index, r.latest_centres_m, r.latest_colors, self.sim_time_s))
            elif outcome == "gap":
                log.info(
                    "scene update %d does not follow %d: asking for a snapshot",
                    update.scene_seq,
                    self.receiver.last_seq,
                )
                self._last_request_s = -float("inf")
        out.new_stream = self.receiver.new_streams > streams
        if self.receiver.tree is None and now_s - self._last_request_s >= self.request_period_s:
            reason = "no map yet" if self.receiver.applied == 0 else "missed an update"
            out.request = SceneRequest(self.receiver.last_seq, reason)
            self.requests += 1
            self._last_request_s = now_s
        return out
