"""The water, and what no drag model carries: its density; buoyancy at the centre of volume of each wet
body (the arm's links; the hull's too under MuJoCo's ellipsoid model, hydrodynamics.py carries it
under Fossen's); and the current: the water's velocity, which Fossen's model of the hull and the
arm's strip model (strips.py) move relative to, and MuJoCo's ellipsoids take as their `wind`."""

from __future__ import annotations

import math

import mujoco
import numpy as np

WATER_DENSITY_KGPM3 = 1025.0  # sea water; the site's option density for MuJoCo's ellipsoids says the same


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


def wet_geoms(model: mujoco.MjModel) -> np.ndarray:
    """(ngeom,) bool: the wet geoms, those of robot.xml's class "wet" (MuJoCo's ellipsoid fluid
    shape is on for them, whichever model then carries their drag)."""
    return model.geom_fluid[:, 0] > 0.0


class Buoyancy:
    """rho * g * V upwards at the centre of volume of every body with wet geoms, but the `dry`
    bodies (whose buoyancy is another model's)."""

    def __init__(
        self, model: mujoco.MjModel, dry: tuple[str, ...] = (), rho_kgpm3: float = WATER_DENSITY_KGPM3
    ) -> None:
        self.rho_kgpm3 = rho_kgpm3
        self.g_mps2 = float(-model.opt.gravity[2])
        volumes = np.zeros(model.nbody)
        moments = np.zeros((model.nbody, 3))
        dry_bodies = {model.body(name).id for name in dry}
        wet = wet_geoms(model)
        for g in range(model.ngeom):
            if not wet[g] or model.geom_bodyid[g] in dry_bodies:
                continue
            v = geom_volume_m3(model.geom_type[g], model.geom_size[g])
            b = model.geom_bodyid[g]
            volumes[b] += v
            moments[b] += v * model.geom_pos[g]
        self.bodies = np.flatnonzero(volumes)
        self.volume_m3 = volumes[self.bodies]
        self.centre_m_body = moments[self.bodies] / self.volume_m3[:, None]
        self._wrench = np.zeros((len(self.bodies), 6))  # xfrc_applied's rows: the force is constant
        self._wrench[:, 2] = self.rho_kgpm3 * self.g_mps2 * self.volume_m3

    def force_n(self, body_index: int) -> float:
        return self.rho_kgpm3 * self.g_mps2 * float(self.volume_m3[body_index])

    def apply(self, data: mujoco.MjData) -> None:
        """Set xfrc_applied of the wet bodies (world frame, about each body's centre of mass)."""
        b, wrench = self.bodies, self._wrench
        centre_world = data.xpos[b] + np.einsum(
            "bij,bj->bi", data.xmat[b].reshape(-1, 3, 3), self.centre_m_body
        )
        lever_m = centre_world - data.xipos[b]
        # lever x (0, 0, f): numpy's cross on these rows, to the bit, without its overhead
        wrench[:, 3] = lever_m[:, 1] * wrench[:, 2]
        wrench[:, 4] = -lever_m[:, 0] * wrench[:, 2]
        data.xfrc_applied[b] = wrench


class Current:
    """The water's velocity [m/s, world]: a mean by depth (a profile of rows z, vx, vy, vz, linear
    in between, held beyond its ends) plus a first-order Gauss-Markov process on each horizontal
    component, x_dot = -x / T + w, stationary standard deviation sigma (seeded)."""

    def __init__(
        self,
        profile: tuple[tuple[float, float, float, float], ...],
        sigma_mps: float,
        time_constant_s: float,
        rng: np.random.Generator,
    ) -> None:
        rows = np.array(sorted(profile) or [(0.0, 0.0, 0.0, 0.0)], dtype=float)
        self.depths_m, self.mean_mps = rows[:, 0], rows[:, 1:]
        self._mean_by_axis = [self.mean_mps[:, k].copy() for k in range(3)]
        # the same mean at every depth (no profile, the default, or a uniform one): no interpolation
        self._uniform = self.mean_mps[0].copy() if np.all(self.mean_mps == self.mean_mps[0]) else None
        self.sigma_mps = sigma_mps
        self.time_constant_s = time_constant_s
        self.rng = rng
        self.gauss_markov_mps = rng.normal(0.0, sigma_mps, 2) if sigma_mps > 0 else np.zeros(2)
        self._time_s = 0.0

    def velocity_mps_world(self, z_m_world: float) -> np.ndarray:
        if self._uniform is not None:
            velocity = self._uniform.copy()
        else:
            velocity = np.array([np.interp(z_m_world, self.depths_m, mean) for mean in self._mean_by_axis])
        velocity[:2] += self.gauss_markov_mps
        return velocity

    def advance(self, t_s: float) -> None:
        """Move the process on to time t_s [s] (exactly, for any step)."""
        dt, self._time_s = t_s - self._time_s, t_s
        if self.sigma_mps > 0 and dt > 0:
            decay = math.exp(-dt / self.time_constant_s)
            self.gauss_markov_mps = decay * self.gauss_markov_mps + self.rng.normal(
                0.0, self.sigma_mps * math.sqrt(1.0 - decay * decay), 2
            )
