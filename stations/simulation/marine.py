"""What MuJoCo's fluid model leaves out: buoyancy at each body's centre of volume, and a
current as the water's velocity (MuJoCo's `wind`, which its drag and added mass use)."""

from __future__ import annotations

import math

import mujoco
import numpy as np


def geom_volume_m3(kind: int, size: np.ndarray) -> float:
    """Volume of a primitive geom [m^3]; planes, height fields and meshes count as dry."""
    if kind == mujoco.mjtGeom.mjGEOM_BOX:
        return float(8.0 * size[0] * size[1] * size[2])
    if kind == mujoco.mjtGeom.mjGEOM_SPHERE:
        return 4.0 / 3.0 * math.pi * size[0] ** 3
    if kind == mujoco.mjtGeom.mjGEOM_ELLIPSOID:
        return float(4.0 / 3.0 * math.pi * size[0] * size[1] * size[2])
    if kind == mujoco.mjtGeom.mjGEOM_CYLINDER:
        return float(math.pi * size[0] ** 2 * 2.0 * size[1])
    if kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
        return float(math.pi * size[0] ** 2 * 2.0 * size[1] + 4.0 / 3.0 * math.pi * size[0] ** 3)
    return 0.0


class Buoyancy:
    """rho * g * V upwards at the centre of volume of every body with wet geoms (those
    with MuJoCo's ellipsoid fluid model enabled)."""

    def __init__(self, model: mujoco.MjModel) -> None:
        self.rho_kgpm3 = float(model.opt.density)
        self.g_mps2 = float(-model.opt.gravity[2])
        volumes = np.zeros(model.nbody)
        moments = np.zeros((model.nbody, 3))
        for g in range(model.ngeom):
            if model.geom_fluid[g, 0] <= 0.0:  # not wet
                continue
            v = geom_volume_m3(model.geom_type[g], model.geom_size[g])
            b = model.geom_bodyid[g]
            volumes[b] += v
            moments[b] += v * model.geom_pos[g]
        self.bodies = np.flatnonzero(volumes)
        self.volume_m3 = volumes[self.bodies]
        self.centre_m_body = moments[self.bodies] / self.volume_m3[:, None]

    def force_n(self, body_index: int) -> float:
        return self.rho_kgpm3 * self.g_mps2 * float(self.volume_m3[body_index])

    def apply(self, data: mujoco.MjData) -> None:
        """Set xfrc_applied of the wet bodies (world frame, about each body's centre of mass)."""
        b = self.bodies
        centre_world = data.xpos[b] + np.einsum("bij,bj->bi", data.xmat[b].reshape(-1, 3, 3),
                                                self.centre_m_body)
        force = np.zeros((len(b), 3))
        force[:, 2] = self.rho_kgpm3 * self.g_mps2 * self.volume_m3
        data.xfrc_applied[b, :3] = force
        data.xfrc_applied[b, 3:] = np.cross(centre_world - data.xipos[b], force)


class Current:
    """A constant current plus a slow sinusoidal variation in a seeded direction [m/s, world]."""

    def __init__(self, mean_mps_world: tuple[float, float, float], variation_mps: float,
                 period_s: float, rng: np.random.Generator) -> None:
        self.mean = np.array(mean_mps_world)
        direction = rng.normal(size=3)
        direction[2] *= 0.2  # mostly horizontal
        self.variation = variation_mps * direction / np.linalg.norm(direction)
        self.period_s = period_s
        self.phase = float(rng.uniform(0.0, 2.0 * math.pi))

    def velocity_mps_world(self, t_s: float) -> np.ndarray:
        return self.mean + self.variation * math.sin(2.0 * math.pi * t_s / self.period_s + self.phase)

    def apply(self, model: mujoco.MjModel, t_s: float) -> None:
        model.opt.wind[:] = self.velocity_mps_world(t_s)
