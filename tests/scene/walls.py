"""Synthetic scenes for the scene stream's tests: square walls of one colour seen from the
origin, vessel models that have seen them, and their updates as they reach shore (through the
codec). No rendering."""

from __future__ import annotations

import numpy as np

from abyss.interface.messages import SceneUpdate, decode, encode
from abyss.scene.model import SceneModel

RESOLUTION_M = 0.1
SENSOR_M_WORLD = np.zeros(3)


def wall(x_m: float, color: tuple[int, int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Points [m, world] of a 1 m square wall facing the sensor at x = `x_m`, all of one colour."""
    grid = np.arange(-0.475, 0.5, 0.05)
    y, z = np.meshgrid(grid, grid)
    points = np.column_stack((np.full(y.size, x_m), y.ravel(), z.ravel()))
    return points, np.tile(np.array(color, np.uint8), (len(points), 1))


def wall_model(x_m: float, color: tuple[int, int, int]) -> SceneModel:
    """A vessel's model that has seen one wall, with several updates per wall (compressed)."""
    model = SceneModel(RESOLUTION_M, 8.0, max_update_bytes=200)
    model.insert(*wall(x_m, color), SENSOR_M_WORLD)
    return model


def updates(model: SceneModel, sim_time_s: float = 0.0) -> list[SceneUpdate]:
    """What the model has queued, as it arrives on shore (through the codec)."""
    out = []
    while (update := model.next_update(sim_time_s)) is not None:
        out.append(decode("k", encode(update, update.scene_seq, 0.0), SceneUpdate).message)
    return out


def occupied(model: SceneModel) -> set[int]:
    """The keys of the cells the model has published occupied."""
    return set(model.published.keys[model.published.occupied].tolist())
