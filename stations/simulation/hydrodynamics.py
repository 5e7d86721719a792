"""A vehicle's marine model in Fossen's form, applied to MuJoCo's rigid body:

    (M_RB + M_A) nu_dot + C_RB(nu) nu + C_A(nu_r) nu_r + D(nu_r) nu_r + g(eta) = tau

MuJoCo integrates the rigid body (M_RB, C_RB, its weight) as it does every body. This module adds
the rest, relative to the water (nu_r = nu - nu_c, the current nu_c irrotational):
- the added mass M_A into MuJoCo's joint-space inertia itself, between mj_step1 and mj_step2
  (so it is implicit: stable whatever its ratio to the body's mass, exact in the coupling with
  the arm and the contacts);
- C_A(nu_r) nu_r (Coriolis and Munk moment of the added mass), the linear and quadratic damping
  D(nu_r) nu_r and the buoyancy at the centre of buoyancy, as a generalised force.
The coefficients are the robot package's marine model (description/marine.py: `Robot.marine`), about
the body's origin, in its frame. Fossen 2021, "Handbook of Marine Craft Hydrodynamics and Motion
Control", 2nd ed., eq. 6.44 (C_A), 6.57-6.60 (D), 4.6 (g)."""

from __future__ import annotations

import mujoco
import numpy as np

from abyss.description.marine import VehicleModel


def skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


class Fossen:
    """The marine forces on one free-floating body of a MuJoCo model (see the module's text)."""

    def __init__(
        self,
        model: mujoco.MjModel,
        vehicle: VehicleModel,
        body: str = "vehicle",
        rho_kgpm3: float | None = None,
    ) -> None:
        """rho_kgpm3: the water's density [kg/m^3]; None: the model's (its option density)."""
        self.vehicle = vehicle
        self.body = model.body(body).id
        joint = model.body_jntadr[self.body]
        if joint < 0 or model.jnt_type[joint] != mujoco.mjtJoint.mjJNT_FREE:
            raise ValueError(f"body {body!r} has no free joint")
        self.dof = int(model.jnt_dofadr[joint])
        # where each row's block entries sit in MuJoCo's sparse (CSR, lower) inertia matrix
        entries, self._rows, self._columns = [], [], []
        for i in range(6):
            row, start = self.dof + i, model.M_rowadr[self.dof + i]
            columns = list(model.M_colind[start : start + model.M_rownnz[row]])
            wanted = range(self.dof, row + 1)
            if not all(c in columns for c in wanted):
                raise ValueError(
                    f"body {body!r}: MuJoCo keeps its inertia diagonal (a 'simple' body); "
                    f"give it an offset centre of gravity or a child body"
                )
            entries += [start + columns.index(c) for c in wanted]
            self._rows += [i] * len(wanted)
            self._columns += [c - self.dof for c in wanted]
        self._entries = np.array(entries)
        self._flat = np.array(self._rows) * 6 + np.array(self._columns)  # the entries in a 6 x 6, flat
        self._turn = np.eye(6)  # diag(R, I): body velocities to the free joint's (world linear, body angular)
        self._added_mass_linear = vehicle.added_mass[:, :3].copy()
        self.damping = vehicle.linear_damping.tolist(), vehicle.quadratic_damping.tolist()
        self.centre_of_buoyancy_m_body = vehicle.centre_of_buoyancy_m_body.tolist()
        # a diagonal M_A (both shipped vehicles'): `apply` in Python's floats alone, on the entries of
        # the inertia that it changes (the linear block, turned, and the angular diagonal)
        self.diagonal: list[float] | None = None
        if np.count_nonzero(vehicle.added_mass - np.diag(np.diag(vehicle.added_mass))) == 0:
            self.diagonal = np.diag(vehicle.added_mass).tolist()
            pairs = list(zip(self._rows, self._columns, strict=True))
            changed = [(0, 0), (1, 0), (1, 1), (2, 0), (2, 1), (2, 2), (3, 3), (4, 4), (5, 5)]
            self.diagonal_entries = self._entries[[pairs.index(p) for p in changed]]
        rho = float(model.opt.density) if rho_kgpm3 is None else rho_kgpm3
        self.buoyancy_n = float(rho * -model.opt.gravity[2] * vehicle.volume_m3)
        # MuJoCo's own fluid forces kept off the body: a body with no ellipsoid geom falls back to
        # MuJoCo's inertia-box drag, so its geoms keep the ellipsoid model with zero coefficients
        hull = model.geom_bodyid == self.body
        model.geom_fluid[hull, 0] = 1.0
        model.geom_fluid[hull, 1:] = 0.0

    def wrench_n_body(self, nu: np.ndarray, nu_current: np.ndarray, rotation: np.ndarray) -> np.ndarray:
        """-C_A(nu_r) nu_r - D(nu_r) nu_r + buoyancy, and the part of -M_A nu_r_dot that MuJoCo's
        inertia does not hold [N, N m], body frame about the origin. nu: (u, v, w, p, q, r);
        nu_current: the current's linear velocity in the body frame [m/s]; rotation: body to world.
        (Written for speed, in Python's floats: it runs at every physics step, and numpy's calls cost
        more than their arithmetic on 3- and 6-vectors.)"""
        u, vv, w, p, q, r = nu.tolist()
        cu, cv, cw = nu_current.tolist()
        ur, vr, wr = u - cu, vv - cv, w - cw
        nu_r = [ur, vr, wr, p, q, r]
        a1u, a1v, a1w, a2p, a2q, a2r = (self.vehicle.added_mass @ nu_r).tolist()
        # C_A(nu_r) nu_r = (omega x a1, v_r x a1 + omega x a2), a = M_A nu_r (Fossen eq. 6.44)
        coriolis = [
            q * a1w - r * a1v,
            r * a1u - p * a1w,
            p * a1v - q * a1u,
            vr * a1w - wr * a1v + q * a2r - r * a2q,
            wr * a1u - ur * a1w + r * a2p - p * a2r,
            ur * a1v - vr * a1u + p * a2q - q * a2p,
        ]
        linear, quadratic = self.damping
        damping = [(dl + dq * abs(x)) * x for dl, dq, x in zip(linear, quadratic, nu_r, strict=True)]
        # M_A nu_r_dot: MuJoCo's inertia holds M_A T qacc, the rest of nu_r_dot is -(omega x v_r, 0)
        # (the body frame turning under the free joint's world-frame velocity, and the current)
        turning = (self._added_mass_linear @ [q * wr - r * vr, r * ur - p * wr, p * vr - q * ur]).tolist()
        b = self.buoyancy_n
        fx, fy, fz = (b * x for x in rotation[2].tolist())  # R^T (0, 0, B)
        bx, by, bz = self.centre_of_buoyancy_m_body
        restoring = [fx, fy, fz, by * fz - bz * fy, bz * fx - bx * fz, bx * fy - by * fx]
        terms = zip(restoring, coriolis, damping, turning, strict=True)
        return np.array([g - c - d + t for g, c, d, t in terms])

    def apply(
        self, model: mujoco.MjModel, data: mujoco.MjData, current_mps_world: np.ndarray, factor: bool = True
    ) -> None:
        """Between mj_step1 and mj_step2: the generalised force and the added mass (`factor`: and
        MuJoCo's factorisation of the inertia redone; False leaves that to the caller, who adds
        more to the inertia first)."""
        if self.diagonal is not None:
            self._apply_diagonal(data, current_mps_world)
            if factor:
                mujoco.mj_factorM(model, data)
            return
        d = self.dof
        rotation = data.xmat[self.body].reshape(3, 3)
        turn = self._turn  # T^T, with nu = T qvel, T = diag(R^T, I)
        turn[:3, :3] = rotation
        nu = turn.T @ data.qvel[d : d + 6]  # free joint: linear in the world, angular in the body
        tau = self.wrench_n_body(nu, rotation.T @ current_mps_world, rotation)
        data.qfrc_applied[d : d + 6] = turn @ tau
        added = turn @ self.vehicle.added_mass @ turn.T  # T^T M_A T
        data.M[self._entries] += added.take(self._flat)
        if factor:
            mujoco.mj_factorM(model, data)

    def _apply_diagonal(self, data: mujoco.MjData, current_mps_world: np.ndarray) -> None:
        """`apply` for a diagonal M_A: the same equations as `wrench_n_body` and the rest of `apply`,
        written out in Python's floats (a physics step's largest share of Python: numpy's calls
        cost more than their arithmetic on 3- and 6-vectors)."""
        d = self.dof
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = data.xmat[self.body].tolist()  # body to world
        vx, vy, vz, p, q, r = data.qvel[d : d + 6].tolist()  # free joint: linear in the world
        cx, cy, cz = current_mps_world.tolist()
        ur = r00 * vx + r10 * vy + r20 * vz - (r00 * cx + r10 * cy + r20 * cz)  # R^T (v - v_c)
        vr = r01 * vx + r11 * vy + r21 * vz - (r01 * cx + r11 * cy + r21 * cz)
        wr = r02 * vx + r12 * vy + r22 * vz - (r02 * cx + r12 * cy + r22 * cz)
        m1, m2, m3, m4, m5, m6 = self.diagonal  # type: ignore[misc]
        a1u, a1v, a1w, a2p, a2q, a2r = m1 * ur, m2 * vr, m3 * wr, m4 * p, m5 * q, m6 * r
        (l1, l2, l3, l4, l5, l6), (q1, q2, q3, q4, q5, q6) = self.damping
        b = self.buoyancy_n
        fx, fy, fz = b * r20, b * r21, b * r22  # R^T (0, 0, B)
        bx, by, bz = self.centre_of_buoyancy_m_body
        # restoring - C_A(nu_r) nu_r - D(nu_r) nu_r + the turning part of M_A nu_r_dot, as in wrench_n_body
        t1 = fx - (q * a1w - r * a1v) - (l1 + q1 * abs(ur)) * ur + m1 * (q * wr - r * vr)
        t2 = fy - (r * a1u - p * a1w) - (l2 + q2 * abs(vr)) * vr + m2 * (r * ur - p * wr)
        t3 = fz - (p * a1v - q * a1u) - (l3 + q3 * abs(wr)) * wr + m3 * (p * vr - q * ur)
        t4 = (by * fz - bz * fy) - (vr * a1w - wr * a1v + q * a2r - r * a2q) - (l4 + q4 * abs(p)) * p
        t5 = (bz * fx - bx * fz) - (wr * a1u - ur * a1w + r * a2p - p * a2r) - (l5 + q5 * abs(q)) * q
        t6 = (bx * fy - by * fx) - (ur * a1v - vr * a1u + p * a2q - q * a2p) - (l6 + q6 * abs(r)) * r
        data.qfrc_applied[d : d + 6] = (
            r00 * t1 + r01 * t2 + r02 * t3,
            r10 * t1 + r11 * t2 + r12 * t3,
            r20 * t1 + r21 * t2 + r22 * t3,
            t4,
            t5,
            t6,
        )
        # T^T M_A T: R diag(m1, m2, m3) R^T and the angular diagonal
        data.M[self.diagonal_entries] += (
            m1 * r00 * r00 + m2 * r01 * r01 + m3 * r02 * r02,
            m1 * r10 * r00 + m2 * r11 * r01 + m3 * r12 * r02,
            m1 * r10 * r10 + m2 * r11 * r11 + m3 * r12 * r12,
            m1 * r20 * r00 + m2 * r21 * r01 + m3 * r22 * r02,
            m1 * r20 * r10 + m2 * r21 * r11 + m3 * r22 * r12,
            m1 * r20 * r20 + m2 * r21 * r21 + m3 * r22 * r22,
            m4,
            m5,
            m6,
        )
