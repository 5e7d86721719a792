"""Shore's final map of a run, and how well two runs' maps agree (the hybrid runs' tests)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from abyss.interface.messages import SceneUpdate, decode
from abyss.scene.export import SCENE_FILE
from abyss.scene.receiver import SceneReceiver

CELL_M = 0.1  # the vessel's octree resolution


def occupied(run_dir: Path) -> set[tuple[int, int, int]]:
    """Shore's final map of a run: its occupied cells' keys."""
    receiver = SceneReceiver()
    receiver.apply(decode("scene", (run_dir / SCENE_FILE).read_bytes(), SceneUpdate).message)
    centres = receiver.occupied_cells()[0]
    return {(int(x), int(y), int(z)) for x, y, z in np.floor(centres / CELL_M)}


def agreement(mine: set[tuple[int, int, int]], theirs: set[tuple[int, int, int]]) -> float:
    """The share of `mine` with a cell of `theirs` within one cell (its 26 neighbours)."""
    near = [(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)]
    return float(np.mean([any((x + i, y + j, z + k) in theirs for i, j, k in near) for x, y, z in mine]))
