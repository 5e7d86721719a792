"""The arm's marine model: strip theory on each wet link, as the vehicle's is Fossen's (hydrodynamics.py).

Each wet geom of a link (a capsule, cylinder or box) is a member along one of its axes (a box's
longest), cut into strips across that axis (Gauss-Legendre points on the straight part, about one
per diameter; one strip at the centroid of each hemispherical end of a capsule). With the link's
velocity relative to the water nu_r = (v_r, omega) [m/s, rad/s] (body frame, at its centre of mass;
the current v_c is uniform and irrotational: v_r = v - R^T v_c), on its strip k:

    u_k = E_k (v_r + omega x r_k)                          the strip's velocity [m/s], strip frame
    f_k = -c_k * u_k * (|u_n|, |u_n|, |u_a|)               its drag [N], Morison's quadratic term
    c_k = 1/2 rho (C_D w_1 ds, C_D w_2 ds, C_D,ax A_ax / n)  [N s^2/m^2]

E_k: rows e_1, e_2 (across the member) and a (along it) in the body frame; r_k the strip's centre
[m, body frame, from the centre of mass]; u_n = (u_1, u_2) the flow across, u_a along; w_1, w_2
the member's width met by a flow along e_1, e_2 [m] (2 r for a round one, a box's face); ds the
strip's length [m] (a capsule's end: its projected half disc, pi r^2 / 2, for w ds); A_ax the
member's end area [m^2], shared by its n strips. The flow across is the cross-flow principle
(Hoerner 1965, "Fluid-Dynamic Drag", ch. 3; Faltinsen 1990, "Sea Loads on Ships and Offshore
Structures", ch. 7): a round member's drag depends on the velocity across it alone. Each strip's
velocity carries the link's rotation, so the rotational drag is this drag integrated along the
link (a link of length L turning at omega about a joint at its end: rho C_D D L^4 omega^2 / 8 about
the joint; its centre's velocity alone gives half of that).

The link's wrench [N, N m] (body frame, about its centre of mass) is the strips' drag,
sum_k Q_k^T f_k with Q_k = E_k [I, -[r_k]x], plus the added mass's velocity terms (Kirchhoff's
equations; Fossen 2021, "Handbook of Marine Craft Hydrodynamics and Motion Control", eq. 6.44):
-(omega x p_v, v_r x p_v + omega x p_omega), (p_v, p_omega) = M_A,b nu_r, plus its buoyancy, rho g V
up at its centre of volume (marine.Buoyancy's volumes and centres).

The added mass is strip theory too: m_k = C_A rho S_k ds on each axis across the member (S_k the
section: pi r^2 for a round one, C_A = 1 a circular cylinder's; a box's side as a flat plate,
pi (w/2)^2 with w its width across the flow, C_A = 1; DNV-RP-C205, "Environmental Conditions and
Environmental Loads", table A-1), and along it Lamb's k_1 rho V, k_1 that of the prolate spheroid
of the member's length and diameter (Lamb 1932, "Hydrodynamics", sec. 373); so
M_A,b = sum_k Q_k^T diag(m_k) Q_k [kg, kg m, kg m^2] ((v, omega) order). It goes into MuJoCo's
joint-space inertia, as the vehicle's does: sum_b J_b^T M_A,b J_b (J_b the link's Jacobian, from
MuJoCo's cdof), worked out with the drag at the low level's rate and added between mj_step1 and
mj_step2 in every physics step (World.step). So it is implicit (stable for any ratio to the link's
own inertia; a diagonal armature would be too, but would lose the coupling) and it couples the
joints with each other and with the vehicle as the water does; it costs a few entries of the
inertia per step, which Fossen's model refactors anyway. Not modelled: the fluid's inertial force
from the links' velocity-product accelerations (J_dot q_dot: second order in the joint rates; the
servos hold the arm), and a round member's spin about its own axis (skin friction alone: under
1e-4 N m at 1 rad/s here).

Coefficients (`Coefficients`), from the geometry, for the arm's Reynolds numbers (D = 0.1 m at
0.05-1 m/s in sea water: Re = 4e3-8e4, subcritical):
- C_D = 0.82 across a round member: a long circular cylinder's 1.2, reduced for its finite length
  at L/D = 10 (Hoerner 1965 ch. 3; White, "Fluid Mechanics", the drag of finite cylinders: 0.82 at
  L/D = 10). The links are joined end to end: the free ends that relieve the pressure are the
  arm's (upper arm, forearm and wrist: 1.1 m long, 0.1 m thick), not each link's.
- C_D,ax = 0.2 along a member, on its end area: the arm in flow along it is one blunt cylinder
  (about 0.85 on its end area, Hoerner 1965 ch. 3) with skin friction on its side (C_f = 0.005 on
  11 diameters of length: 0.22 more), shared by its five round members.
- C_D = 1.05 on a box's faces (a cube, Hoerner 1965 ch. 3): the gripper's hand and fingers.
- C_A = 1 across a member, k_1 along it (above).

SI units throughout. The wrenches go through MjData.xfrc_applied (world frame, about each body's
centre of mass), held between the low level's updates."""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from abyss.stations.simulation.marine import Buoyancy


@dataclass(frozen=True)
class Coefficients:
    """See the module's text for their sources."""

    cross_flow_drag: float = 0.82  # C_D, a round member across its axis (on D ds)
    axial_drag: float = 0.2  # C_D,ax, along a member (on its end area)
    box_drag: float = 1.05  # C_D, on a box's faces
    added_mass: float = 1.0  # C_A, across a member (on its section)


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def gauss_legendre(n: int, half_length_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Points and weights [m] of n-point Gauss-Legendre quadrature on [-half_length, half_length]."""
    x, w = np.polynomial.legendre.leggauss(n)
    return x * half_length_m, w * half_length_m


def lamb_axial(length_m: float, diameter_m: float) -> float:
    """Lamb's k_1: the axial added mass of a prolate spheroid of this length and diameter over its
    displaced mass (Lamb 1932, sec. 373); 0.5 for a sphere."""
    a, b = max(length_m, diameter_m) / 2.0, min(length_m, diameter_m) / 2.0
    if a - b < 1e-9 * a:
        return 0.5
    e = math.sqrt(1.0 - (b / a) ** 2)
    alpha = 2.0 * (1.0 - e * e) / e**3 * (0.5 * math.log((1.0 + e) / (1.0 - e)) - e)
    return alpha / (2.0 - alpha)


@dataclass
class _Strips:
    """A member's strips, in the geom's frame with its axis along `axis`."""

    s_m: np.ndarray  # (n,) along the axis
    drag_n: np.ndarray  # (n, 3) 1/2 rho C w ds per axis of the geom [N s^2/m^2] (along the axis: 0)
    mass_kg: np.ndarray  # (n, 3) added mass per axis of the geom (along the axis: 0)
    axial_drag: float  # 1/2 rho C_ax A_ax, the member's [N s^2/m^2]
    axial_mass_kg: float  # the member's


def _member(kind: int, size: np.ndarray, rho: float, c: Coefficients) -> tuple[int, _Strips]:
    """The strips of one geom; raises ValueError for a shape this model has no member for."""
    if kind in (mujoco.mjtGeom.mjGEOM_CAPSULE, mujoco.mjtGeom.mjGEOM_CYLINDER):
        r, h = float(size[0]), float(size[1])
        n = max(2, math.ceil(h / r))  # about one strip per diameter
        s, ds = gauss_legendre(n, h)
        widths = np.full(n, 2.0 * r) * ds  # projected area of each strip
        sections = np.full(n, math.pi * r * r) * ds
        volume = math.pi * r * r * 2.0 * h
        length = 2.0 * h
        if kind == mujoco.mjtGeom.mjGEOM_CAPSULE:  # each end a hemisphere, one strip at its centroid
            cap = h + 4.0 * r / (3.0 * math.pi)
            s = np.r_[-cap, s, cap]
            widths = np.r_[math.pi * r * r / 2.0, widths, math.pi * r * r / 2.0]
            sections = np.r_[2.0 / 3.0 * math.pi * r**3, sections, 2.0 / 3.0 * math.pi * r**3]
            volume += 4.0 / 3.0 * math.pi * r**3
            length += 2.0 * r
        drag = 0.5 * rho * c.cross_flow_drag * widths
        mass = rho * c.added_mass * sections
        strips = _Strips(
            s,
            np.c_[drag, drag, np.zeros_like(drag)],
            np.c_[mass, mass, np.zeros_like(mass)],
            0.5 * rho * c.axial_drag * math.pi * r * r,
            lamb_axial(length, 2.0 * r) * rho * volume,
        )
        return 2, strips
    if kind == mujoco.mjtGeom.mjGEOM_BOX:
        half = np.asarray(size[:3], dtype=float)
        axis = int(np.argmax(half))
        j, k = (axis + 1) % 3, (axis + 2) % 3
        n = max(2, math.ceil(half[axis] / max(half[j], half[k])))
        s, ds = gauss_legendre(n, float(half[axis]))
        drag, mass = np.zeros((n, 3)), np.zeros((n, 3))
        drag[:, j] = 0.5 * rho * c.box_drag * 2.0 * half[k] * ds  # a flow along j meets the j face
        drag[:, k] = 0.5 * rho * c.box_drag * 2.0 * half[j] * ds
        mass[:, j] = rho * c.added_mass * math.pi * half[k] ** 2 * ds  # a plate as wide as the face
        mass[:, k] = rho * c.added_mass * math.pi * half[j] ** 2 * ds
        volume = 8.0 * half[0] * half[1] * half[2]
        diameter = 2.0 * math.sqrt(half[j] * half[k] * 4.0 / math.pi)  # of the same section
        strips = _Strips(
            s,
            drag,
            mass,
            0.5 * rho * c.box_drag * 4.0 * half[j] * half[k],
            lamb_axial(2.0 * half[axis], diameter) * rho * volume,
        )
        return axis, strips
    raise ValueError(f"no strip model for a geom of type {mujoco.mjtGeom(kind).name}")


# -[v]x = v @ _SKEW, as (3, 3) rows (a product where numpy's np.cross costs ten times as much)
_SKEW = np.array([-_skew(e).ravel() for e in np.eye(3)])


def _block_diagonal(blocks: list[np.ndarray]) -> np.ndarray:
    rows, columns = sum(b.shape[0] for b in blocks), sum(b.shape[1] for b in blocks)
    out, i, j = np.zeros((rows, columns)), 0, 0
    for b in blocks:
        out[i : i + b.shape[0], j : j + b.shape[1]] = b
        i, j = i + b.shape[0], j + b.shape[1]
    return out


def _kirchhoff(added_mass: np.ndarray) -> np.ndarray:
    """(6, 36): the added mass's velocity terms as a bilinear form, -C_A(nu) nu = K (nu (x) nu),
    -C_A(nu) nu = -(omega x p_v, v x p_v + omega x p_omega), p = M_A nu (Fossen 2021, eq. 6.44)."""
    k = np.zeros((6, 6, 6))
    for j in range(6):
        for i in range(6):
            x, p = np.eye(6)[j], added_mass @ np.eye(6)[i]
            k[:, j, i] = -np.r_[np.cross(x[3:], p[:3]), np.cross(x[:3], p[:3]) + np.cross(x[3:], p[3:])]
    return k.reshape(6, 36)


def _span(ids: np.ndarray) -> slice | np.ndarray:
    """A slice where the ids run on one by one (numpy then takes views, not copies)."""
    if len(ids) and np.array_equal(ids, np.arange(ids[0], ids[0] + len(ids))):
        return slice(int(ids[0]), int(ids[0]) + len(ids))
    return ids


def _strip_rows(
    model: mujoco.MjModel, bodies: np.ndarray, wet: np.ndarray, rho: float, coefficients: Coefficients
) -> tuple[list[np.ndarray], list[list[float]], list[list[float]], list[int]]:
    """Every strip of the wet geoms of `bodies`, link by link: its Q_k (3, 6) (body frame, about the
    centre of mass), drag and added mass per axis of the strip frame, and its link's index."""
    rows: list[np.ndarray] = []  # Q_k (3, 6), body frame about the centre of mass
    drag: list[list[float]] = []
    mass: list[list[float]] = []
    owner: list[int] = []
    for i, b in enumerate(bodies):
        for g in np.flatnonzero((model.geom_bodyid == b) & wet):
            axis, strips = _member(int(model.geom_type[g]), model.geom_size[g], rho, coefficients)
            flat_rotation = np.empty(9)
            mujoco.mju_quat2Mat(flat_rotation, model.geom_quat[g])
            rotation = flat_rotation.reshape(3, 3)  # geom to body
            order = [(axis + 1) % 3, (axis + 2) % 3, axis]  # the strip frame: across, across, along
            frame = rotation[:, order].T  # rows e_1, e_2, a in the body frame
            share = 1.0 / len(strips.s_m)  # of the axial terms: the strips all move alike along it
            for s, d, m in zip(strips.s_m, strips.drag_n, strips.mass_kg, strict=True):
                r = model.geom_pos[g] + s * rotation[:, axis] - model.body_ipos[b]
                rows.append(frame @ np.hstack([np.eye(3), -_skew(r)]))
                drag.append([d[order[0]], d[order[1]], strips.axial_drag * share])
                mass.append([m[order[0]], m[order[1]], strips.axial_mass_kg * share])
                owner.append(i)
    if not rows:
        raise ValueError("no wet geoms on the links")
    return rows, drag, mass, owner


def _buoyancy_terms(model: mujoco.MjModel, bodies: np.ndarray, buoyancy: Buoyancy) -> np.ndarray:
    """(nb, 6, 3): each link's buoyancy, rho g V up at its centre of volume c, as
    (f, c x f) = G (rho g V R^T e_z), about its centre of mass."""
    index = [list(buoyancy.bodies).index(b) for b in bodies]
    lift_n = buoyancy.rho_kgpm3 * buoyancy.g_mps2 * buoyancy.volume_m3[index]
    levers = buoyancy.centre_m_body[index] - model.body_ipos[bodies]
    return np.array([f * np.vstack([np.eye(3), _skew(r)]) for f, r in zip(lift_n, levers, strict=True)])


def _chain(model: mujoco.MjModel, body: int) -> set[int]:
    """The dofs that move `body`: its own and its ancestors'."""
    dofs: set[int] = set()
    while body > 0:
        start, count = model.body_dofadr[body], model.body_dofnum[body]
        dofs.update(range(start, start + count))
        body = int(model.body_parentid[body])
    return dofs


def _inertia_entries(
    model: mujoco.MjModel, dofs: np.ndarray, mask: np.ndarray
) -> tuple[list[int], list[int]]:
    """Where the pairs of `dofs` sit in MuJoCo's sparse lower inertia (M's entries), and each
    one's index in the dofs x dofs matrix; raises ValueError for a pair that moves one link
    (`mask`: (nb, 1, nd), which dofs move each) but has no entry."""
    entries, flat = [], []
    nd = len(dofs)
    for a in range(nd):
        row = int(dofs[a])
        start, count = model.M_rowadr[row], model.M_rownnz[row]
        columns = list(model.M_colind[start : start + count])
        for k in range(a + 1):
            column = int(dofs[k])
            if column in columns:
                entries.append(start + columns.index(column))
                flat.append(a * nd + k)
            elif (mask[:, 0, a] * mask[:, 0, k]).any():
                raise ValueError(
                    f"dofs {row} and {column} move one link but share no entry of MuJoCo's inertia"
                )
    return entries, flat


class ArmStrips:
    """The strip model of the wet links `bodies` (body ids) of a MuJoCo model: see the module's text.

    `apply` (at the low level's rate) sets each link's xfrc_applied to its drag, the added mass's
    velocity terms and its buoyancy, and works out the added mass in joint space; `add_mass` (every
    physics step, between mj_step1 and mj_step2, before mj_factorM) puts that into MuJoCo's inertia.
    Twists, wrenches and the added mass are taken about each link's centre of mass, in its body frame."""

    def __init__(
        self,
        model: mujoco.MjModel,
        bodies: list[int],
        buoyancy: Buoyancy,
        wet: np.ndarray,
        coefficients: Coefficients = Coefficients(),
        added_inertia: bool = True,
    ) -> None:
        """`buoyancy`: the water's density and each link's volume and centre (all of `bodies` among
        its bodies); `wet`: (ngeom,) which geoms are wet, each body's wet geoms make its members.
        `added_inertia` False leaves the added mass's inertial term -M_A nu_dot out (MuJoCo's
        ellipsoid model has none: for comparisons with it)."""
        self.coefficients = coefficients
        self.bodies = np.array(bodies, dtype=int)
        self.added_inertia = added_inertia
        self._strip_terms(model, buoyancy, wet)
        self._joint_space(model)
        # the wrenches' three parts in one product: the strips' drag forces, the velocities' products
        # and the vertical in the body frame to each link's (force, moment)
        self._wrench = np.hstack(
            [
                -self._q.T,
                _block_diagonal(list(self._kirchhoff)),
                _block_diagonal(list(self._buoyancy)),
            ]
        )
        self._speed = np.array([[1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 1.0]])  # |u_n|^2, |u_n|^2, u_a^2

    def _strip_terms(self, model: mujoco.MjModel, buoyancy: Buoyancy, wet: np.ndarray) -> None:
        """The constant body-frame terms: the strips' Q_k and drag, each link's added mass, its
        Kirchhoff form and its buoyancy."""
        nb = len(self.bodies)
        rows, drag, mass, owner = _strip_rows(model, self.bodies, wet, buoyancy.rho_kgpm3, self.coefficients)
        n = len(rows)
        self.strip_count = n
        self.owner = np.array(owner)  # each strip's link (they come link by link)
        self._drag = np.array(drag)  # (n, 3) [N s^2/m^2]
        q = np.zeros((3 * n, 6 * nb))  # all strips' Q_k, block by block
        for k, (strip_rows, i) in enumerate(zip(rows, owner, strict=True)):
            q[3 * k : 3 * k + 3, 6 * i : 6 * i + 6] = strip_rows
        self._q, self._q_t = q, np.ascontiguousarray(q.T)
        m = np.array(mass).ravel()
        self._added_mass = q.T @ (m[:, None] * q)  # sum_k Q_k^T diag(m_k) Q_k: block-diagonal
        self.added_mass = np.array(
            [self._added_mass[6 * i : 6 * i + 6, 6 * i : 6 * i + 6] for i in range(nb)]
        )
        self._kirchhoff = np.array([_kirchhoff(m) for m in self.added_mass])  # (nb, 6, 36)
        self._buoyancy = _buoyancy_terms(model, self.bodies, buoyancy)

    def _joint_space(self, model: mujoco.MjModel) -> None:
        """The dofs that move a link, where their pairs sit in MuJoCo's sparse lower inertia (every
        link hangs from the same root), and the buffers `jacobians` and `apply` fill."""
        nb = len(self.bodies)
        self.root = int(model.body_rootid[self.bodies[0]])
        chains = [_chain(model, b) for b in self.bodies]
        self.dofs = np.array(sorted(set().union(*chains)), dtype=int)
        self._mask = np.array([[d in chain for d in self.dofs] for chain in chains], dtype=float)[:, None, :]
        entries, flat = _inertia_entries(model, self.dofs, self._mask)
        nd = len(self.dofs)
        self.entries = np.array(entries, dtype=int)
        self.flat = np.array(flat, dtype=int)  # per entry: its index in the dofs x dofs matrix
        self.values = np.zeros(len(entries))
        self._b, self._d = _span(self.bodies), _span(self.dofs)
        self._x = np.zeros((nb, 6, 6))  # com-based (omega, v) to each link's (v, omega), see `jacobians`
        self.jacobian = np.zeros((nb, 6, nd))  # body frame, about the centre of mass, at the last `apply`
        self.mass_q = np.zeros((nd, nd))  # the added mass in joint space, at the last `apply`

    def tables(self) -> dict[str, np.ndarray]:
        """The model's constant tables, each C-contiguous, as native_physics.c takes them: per
        strip its Q_k (3, 6) and drag (3,), per link its Kirchhoff form (6, 36), buoyancy (6, 3),
        added mass (6, 6) and dof mask, per inertia entry its index in the dofs x dofs matrix."""
        n, nb = self.strip_count, len(self.bodies)
        q = np.array([self._q[3 * k : 3 * k + 3, 6 * i : 6 * i + 6] for k, i in enumerate(self.owner)])
        tables = {
            "q": q.reshape(n, 18),
            "drag": self._drag,
            "kirchhoff": self._kirchhoff.reshape(nb, 216),
            "buoyancy": self._buoyancy.reshape(nb, 18),
            "added_mass": self.added_mass.reshape(nb, 36),
            "mask": self._mask.reshape(nb, -1),
        }
        return {name: np.ascontiguousarray(table, dtype=float) for name, table in tables.items()}

    def jacobians(self, data: mujoco.MjData) -> np.ndarray:
        """(nb, 6, nd): each link's (v, omega) per joint velocity, body frame about its centre of
        mass, from MuJoCo's cdof (each dof's motion, (omega, v) at the root's subtree centre of mass
        c, world axes) of the last kinematics: (v, omega)_b = X_b cdof, with
        X_b = [[-R^T [p_b - c]x, R^T], [R^T, 0]] (p_b the link's centre of mass, R its rotation)."""
        b, nb = self._b, len(self.bodies)
        rotation_t = data.xmat[b].reshape(nb, 3, 3).transpose(0, 2, 1)
        lever = data.xipos[b] - data.subtree_com[self.root]
        x = self._x
        x[:, :3, :3] = rotation_t @ (lever @ _SKEW).reshape(nb, 3, 3)
        x[:, :3, 3:] = rotation_t
        x[:, 3:, :3] = rotation_t
        np.matmul(x, data.cdof[self._d].T, out=self.jacobian)
        self.jacobian *= self._mask
        return self.jacobian

    def wrenches_n_body(self, nu: np.ndarray, vertical: np.ndarray) -> np.ndarray:
        """(nb, 6) force [N] and moment [N m] on each link, body frame about its centre of mass: the
        strips' drag and the added mass's velocity terms from its twist relative to the water `nu`
        (nb, 6), and its buoyancy from `vertical` (nb, 3), the world's z in its frame."""
        u = (self._q @ nu.ravel()).reshape(-1, 3)  # each strip's velocity in its frame
        speed = np.sqrt((u * u) @ self._speed)
        products = nu[:, :, None] * nu[:, None, :]
        parts = np.concatenate(((self._drag * speed * u).ravel(), products.ravel(), vertical.ravel()))
        return (self._wrench @ parts).reshape(-1, 6)

    def apply(self, data: mujoco.MjData, water_mps_world: np.ndarray) -> None:
        """Set the links' xfrc_applied and work out the joint-space added mass (see the class)."""
        b, nb = self._b, len(self.bodies)
        rotation = data.xmat[b].reshape(nb, 3, 3)
        x = self._x  # X_b, as in `jacobians`
        x[:, :3, 3:] = x[:, 3:, :3] = rotation_t = rotation.transpose(0, 2, 1)
        lever = data.xipos[b] - data.subtree_com[self.root]
        x[:, :3, :3] = rotation_t @ (lever @ _SKEW).reshape(nb, 3, 3)
        relative = data.cvel[b].copy()
        relative[:, 3:] -= water_mps_world  # the current: a uniform translation
        nu = (x @ relative[:, :, None])[:, :, 0]
        wrench = self.wrenches_n_body(nu, rotation[:, 2])
        world = rotation @ wrench.reshape(nb, 2, 3).transpose(0, 2, 1)  # (nb, 3, 2): force, moment
        data.xfrc_applied[b] = world.transpose(0, 2, 1).reshape(nb, 6)
        if self.added_inertia:
            jacobian = np.matmul(x, data.cdof[self._d].T, out=self.jacobian)
            jacobian *= self._mask
            flat = jacobian.reshape(6 * nb, -1)
            self.mass_q = flat.T @ (self._added_mass @ flat)
            self.mass_q.ravel().take(self.flat, out=self.values)

    def add_mass(self, data: mujoco.MjData) -> None:
        """Between mj_step1 and mj_step2, before mj_factorM: the added mass into the inertia."""
        data.M[self.entries] += self.values
