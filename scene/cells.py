"""Sets of octree cells by packed key (`octree.cell_keys`): what the vessel's model has published
and what it has queued, each cell occupied or free with a colour."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from abyss.scene.octree import COLOR_TOLERANCE, GREY, morton


class Lookup(NamedTuple):
    """Cells looked up in a CellSet: whether each is there, its state and colour."""

    found: np.ndarray
    occupied: np.ndarray
    colors: np.ndarray

    def of(self, chosen: np.ndarray) -> Lookup:
        return Lookup(self.found[chosen], self.occupied[chosen], self.colors[chosen])


def moved(a_rgb: np.ndarray, b_rgb: np.ndarray) -> np.ndarray:
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
