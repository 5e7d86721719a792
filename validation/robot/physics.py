"""The physics `abyss robot check` holds a robot package to (validation/robot/check.py): the
simulation's own physics step (stations/simulation/physics.py, which the World flies on its site)
flown on the robot alone, and what the numbers of robot.toml predict of it.

`Bench` is the package's model alone (description.robot.robot_spec, compiled; the physics step
0.002 s) in the simulation's `MarinePhysics` with `hydrodynamics = "fossen"` (Fossen's model on the
vehicle, its buoyancy at the centre of buoyancy) and `arm_hydrodynamics = "none"` (the arm's
buoyancy, no drag), driven open loop through the thrusters' rotors (thrusters.Thrusters: the lag,
the dead band, the quadratic curve) at the low level's rate. The arm is held stowed and rigid (stiff
springs on its joints at `stowed_rad`, the gripper closed) and carries no drag, so that what is
measured is the vehicle's model alone, the one the analytic figures are worked from; the stowed arm
still adds its mass, inertia and buoyancy, as it does in the water.

`hydrostatics` is what the package floats like, stowed, in the rest pose: weight against
buoyancy, the centres, the righting coefficient W BG_z and the roll and pitch periods it gives with
the rigid and added inertia. `open_loop` and `decay` run the bench: a thrust held from rest until
the speed settles, and a release from a heel. Where the package's configuration holds roll and
pitch (simulation.attitude_kp/kd), the open-loop runs fly with that hold, as the simulation's low
level applies it (stations/simulation/attitude.py `AttitudeHold`, which a small ROV's autopilot
stands for); the decays stay free, since they measure the restoring moment."""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from abyss.description.robot import HEAVE, Robot, robot_spec
from abyss.stations.simulation.attitude import AttitudeHold
from abyss.stations.simulation.physics import MarinePhysics
from abyss.stations.simulation.thrusters import Thrusters

PHYSICS_STEP_S = 0.002
LOW_LEVEL_STEPS = 5  # the thrusters' rotors move on every 5 physics steps (0.01 s), as the low level's
SAMPLE_S = 0.05  # a trace's sample period [s]
# the arm held stowed: springs stiff enough that its drag-free, neutral links barely bend (a 50 N m
# load moves a joint 0.01 rad) and slow enough for an explicit spring at the step (omega dt < 0.3)
ARM_STIFFNESS_NM_PER_RAD = 5000.0
ARM_DAMPING_NMS_PER_RAD = 200.0
SETTLE_WINDOW_S = 2.0  # a run is steady when, over this, its speed changed less than SETTLE_CHANGE
SETTLE_CHANGE = 1e-3  # of itself
SETTLE_ANGLE_RAD = 1e-3  # ... and its roll and pitch less than this (a vehicle tumbling never is)
SETTLE_MIN_S = 5.0
RUN_MAX_S = 60.0


@dataclass(frozen=True)
class Hydrostatics:
    """The robot floating stowed, level: body frame, about the vehicle's origin."""

    mass_kg: float  # the whole robot's, the arm's links included [kg]
    weight_n: float  # [N]
    buoyancy_n: float  # the hull's (robot.toml) and the arm's links' [N]
    gravity_m_body: np.ndarray  # (3,) the centre of gravity [m]
    buoyancy_m_body: np.ndarray  # (3,) the centre of buoyancy [m]
    rigid_inertia: np.ndarray  # (2,) roll, pitch, about the origin [kg m^2]
    added_inertia: np.ndarray  # (2,) roll, pitch: M_A's diagonal [kg m^2]
    effective_inertia: np.ndarray  # (2,) roll, pitch, the other axes free (see `inertia_free`) [kg m^2]
    linear_damping: np.ndarray  # (2,) roll, pitch [N m s/rad]

    @property
    def net_n(self) -> float:
        """Buoyancy less weight: > 0 floats up [N]."""
        return self.buoyancy_n - self.weight_n

    @property
    def bg_m(self) -> np.ndarray:
        """From the centre of gravity to that of buoyancy [m]; z > 0: the vehicle rights itself."""
        return self.buoyancy_m_body - self.gravity_m_body

    @property
    def righting_nm_per_rad(self) -> float:
        """W BG_z, the righting moment per radian of heel in roll and in pitch [N m/rad]."""
        return self.weight_n * float(self.bg_m[2])

    def period_s(self, k: int) -> float:
        """The undamped natural period in roll (k = 0) or pitch (1) [s]; inf where not righting."""
        stiffness = self.righting_nm_per_rad
        return 2.0 * math.pi * math.sqrt(self.effective_inertia[k] / stiffness) if stiffness > 0 else math.inf

    def damped_period_s(self, k: int) -> float:
        """As `period_s`, with the linear damping's ratio zeta: T / sqrt(1 - zeta^2) [s]."""
        stiffness = self.righting_nm_per_rad
        if stiffness <= 0:
            return math.inf
        zeta = self.linear_damping[k] / (2.0 * math.sqrt(stiffness * self.effective_inertia[k]))
        return self.period_s(k) / math.sqrt(1.0 - zeta * zeta) if zeta < 1.0 else math.inf


@dataclass(frozen=True)
class Trace:
    """A bench run, sampled every SAMPLE_S: time [s], body velocity (u, v, w [m/s], p, q, r
    [rad/s]) and roll, pitch, yaw [rad]."""

    time_s: np.ndarray
    nu_body: np.ndarray  # (k, 6)
    rpy_rad: np.ndarray  # (k, 3)


class Bench:
    """The robot's model with the simulation's marine terms (see the module's text); `hold` is the
    package's attitude hold (none held with zero gains, the default), which `run` applies on asking."""

    def __init__(
        self,
        robot: Robot,
        attitude_kp: tuple[float, float] = (0.0, 0.0),
        attitude_kd: tuple[float, float] = (0.0, 0.0),
    ) -> None:
        """`attitude_kp` [N m/rad] and `attitude_kd` [N m/(rad/s)]: roll's, then pitch's, as the
        configuration's simulation.attitude_kp/kd."""
        self.robot = robot
        self.model = model = robot_spec(robot).compile()
        model.opt.timestep = PHYSICS_STEP_S
        self.vehicle = robot.marine
        self.data = mujoco.MjData(model)
        # the arm carries no drag (see the module's text)
        self.physics = MarinePhysics(model, self.data, robot, "fossen", "none")
        assert self.physics.fossen is not None
        self.fossen = self.physics.fossen
        self.thrusters = Thrusters(model, self.vehicle.thrusters, robot.allocation)
        self.hold = AttitudeHold(self.thrusters, attitude_kp, attitude_kd)
        self.body = model.body(robot.base).id
        joint = model.joint(robot.base)
        self.qpos, self.dof = int(joint.qposadr[0]), int(joint.dofadr[0])
        self.held = [(model.joint(n), a) for n, a in zip(robot.arm_joints, robot.stowed_rad, strict=True)]
        self.held += [(model.joint(n), 0.0) for n in robot.gripper_joints]
        for joint_, angle in self.held:
            model.jnt_stiffness[joint_.id] = ARM_STIFFNESS_NM_PER_RAD
            model.qpos_spring[joint_.qposadr[0]] = angle
            model.dof_damping[joint_.dofadr[0]] = ARM_DAMPING_NMS_PER_RAD
        self.reset()

    def reset(self, rpy_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> None:
        """At rest at the origin, turned by `rpy_rad`, the arm stowed, the rotors stopped."""
        m, d = self.model, self.data
        mujoco.mj_resetData(m, d)
        quat = np.empty(4)
        mujoco.mju_euler2Quat(quat, np.asarray(rpy_rad, dtype=float), "XYZ")  # intrinsic: yaw, pitch, roll
        d.qpos[self.qpos : self.qpos + 7] = (0.0, 0.0, 0.0, *quat)
        for joint, angle in self.held:
            d.qpos[joint.qposadr[0]] = angle
        self.thrusters.rotor_speed[:] = 0.0
        mujoco.mj_forward(m, d)

    def run(
        self, thrust_n: np.ndarray, duration_s: float, settle: int | None = None, attitude: bool = False
    ) -> Trace:
        """Hold the thrusts `thrust_n` [N] (commanded through the rotors) for `duration_s` [s], or,
        with `settle` (a row of nu), until that velocity and the roll and pitch are steady (at most
        RUN_MAX_S). `attitude`: with the attitude hold, where it holds an axis (see `commanded`)."""
        d = self.data
        water = np.zeros(3)
        every = round(SAMPLE_S / PHYSICS_STEP_S)  # a multiple of LOW_LEVEL_STEPS
        window = round(SETTLE_WINDOW_S / SAMPLE_S)
        rows: list[list[float]] = [self._sample()]
        steps = round((RUN_MAX_S if settle is not None else duration_s) / PHYSICS_STEP_S)
        for k in range(0, steps, LOW_LEVEL_STEPS):  # the thrusters and the held forces, then the steps
            thrust = self.commanded(thrust_n) if attitude else thrust_n
            self.thrusters.apply(d, thrust, LOW_LEVEL_STEPS * PHYSICS_STEP_S)
            self.physics.forces(water)
            self.physics.step(water, min(LOW_LEVEL_STEPS, steps - k))
            if (k + LOW_LEVEL_STEPS) % every:
                continue
            rows.append(self._sample())
            if settle is not None and d.time >= SETTLE_MIN_S and len(rows) > window:
                now, before = rows[-1], rows[-1 - window]
                speed = abs(now[1 + settle] - before[1 + settle]) <= SETTLE_CHANGE * abs(now[1 + settle])
                if speed and max(abs(now[7] - before[7]), abs(now[8] - before[8])) <= SETTLE_ANGLE_RAD:
                    break
        table = np.array(rows)
        return Trace(table[:, 0], table[:, 1:7], table[:, 7:10])

    def commanded(self, thrust_n: np.ndarray) -> np.ndarray:
        """The thrusts [N] for `thrust_n`'s wrench on the actuated axes with the hold's roll and pitch
        moments from the body's attitude now, allocated and scaled into the thrusters' limits together
        (AttitudeHold.allocate, as the low level does); `thrust_n` itself where nothing is held."""
        if not self.hold.held:
            return thrust_n
        d = self.data
        rotation = d.xmat[self.body].reshape(3, 3)
        rates = d.qvel[self.dof + 3 : self.dof + 5]  # the free joint's angular velocity: body frame
        actuated = self.thrusters.actuated_allocation @ thrust_n
        return self.hold.allocate(np.r_[actuated, self.hold.moment(rotation, rates)])

    def _sample(self) -> list[float]:
        d = self.data
        rotation = d.xmat[self.body].reshape(3, 3)
        velocity = d.qvel[self.dof : self.dof + 6]
        w, x, y, z = d.qpos[self.qpos + 3 : self.qpos + 7] / np.linalg.norm(
            d.qpos[self.qpos + 3 : self.qpos + 7]
        )
        roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
        pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
        yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
        return [d.time, *(rotation.T @ velocity[:3]), *velocity[3:], roll, pitch, yaw]


def hydrostatics(bench: Bench) -> Hydrostatics:
    """The robot at rest, level and stowed (see `Hydrostatics`)."""
    bench.reset()
    m, d = bench.model, bench.data
    g = float(-m.opt.gravity[2])
    origin, rotation = d.xpos[bench.body], d.xmat[bench.body].reshape(3, 3)
    mass = float(m.body_subtreemass[bench.body])
    gravity = rotation.T @ (d.subtree_com[bench.body] - origin)
    hull = bench.fossen.buoyancy_n
    arm = bench.physics.buoyancy
    arm_forces = np.array([arm.force_n(i) for i in range(len(arm.bodies))])
    arm_centres = d.xpos[arm.bodies] + np.einsum(
        "bij,bj->bi", d.xmat[arm.bodies].reshape(-1, 3, 3), arm.centre_m_body
    )
    moments = hull * bench.vehicle.centre_of_buoyancy_m_body + arm_forces @ (arm_centres - origin) @ rotation
    lift = hull + float(arm_forces.sum())
    inertia = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(m, d, inertia)
    dofs = slice(bench.dof, bench.dof + 6)
    rigid = inertia[dofs, dofs]  # the arm rigid: its dofs held
    return Hydrostatics(
        mass_kg=mass,
        weight_n=mass * g,
        buoyancy_n=lift,
        gravity_m_body=gravity,
        buoyancy_m_body=moments / lift,
        rigid_inertia=np.diag(rigid)[3:5].copy(),
        added_inertia=np.diag(bench.vehicle.added_mass)[3:5].copy(),
        effective_inertia=inertia_free(rigid + bench.vehicle.added_mass)[3:5],
        linear_damping=bench.vehicle.linear_damping[3:5].copy(),
    )


def inertia_free(mass: np.ndarray) -> np.ndarray:
    """(6,) The inertia each axis of a free body meets when the other axes are free to move
    (no stiffness, no damping on them), 1 / (M^-1)_kk: in roll, a vehicle whose centre of gravity
    sits below its origin sways as it rolls (M's sway-roll term, -m z_G), which takes
    (m z_G)^2 / (m + A_22) off its inertia about the origin. The free axes are not quite free
    (their damping), but their time constants (tens of seconds in sway) are far longer than the
    periods (seconds), which is what the bound on the measured period allows for."""
    return 1.0 / np.diag(np.linalg.inv(mass))


def terminal_speed(linear: float, quadratic: float, force: float) -> float:
    """The speed where a force [N or N m] meets linear and quadratic damping, d_l u + d_q u|u| = F
    [m/s or rad/s], signed as the force; inf where nothing damps it."""
    magnitude = abs(force)
    if quadratic > 0:
        speed = (-linear + math.sqrt(linear * linear + 4.0 * quadratic * magnitude)) / (2.0 * quadratic)
    else:
        speed = magnitude / linear if linear > 0 else math.inf
    return math.copysign(speed, force)


def measured_period_s(time_s: np.ndarray, angle_rad: np.ndarray) -> float:
    """The period of an oscillation about a level [s]: the mean interval between its crossings of
    that level (interpolated) in the same direction, over its first seven crossings (so that an
    error in the level, which moves the up and down crossings apart, cancels); nan where it
    crosses fewer than three times. The level: the middle of the last third's extremes (the
    oscillation, decaying, is smallest there)."""
    tail = angle_rad[-max(len(angle_rad) // 3, 1) :]
    offset = angle_rad - 0.5 * (tail.max() + tail.min())
    signs = np.signbit(offset)
    where = np.flatnonzero(signs[1:] != signs[:-1])[:7]
    if len(where) < 3:
        return math.nan
    a, b = offset[where], offset[where + 1]
    crossings = time_s[where] + (time_s[where + 1] - time_s[where]) * a / (a - b)
    return float(np.mean(crossings[2:] - crossings[:-2]))


@dataclass(frozen=True)
class Response:
    """An open-loop run: a thrust held from rest along one axis (a wrench row: 0-2 surge, sway,
    heave; 5 yaw), its speed along that axis over time [m/s or rad/s], and the terminal speed
    the damping gives that thrust."""

    axis: int
    sign: int  # +1, -1
    time_s: np.ndarray
    speed: np.ndarray
    analytic: float
    settled: bool  # steady before RUN_MAX_S
    heel_rad: float  # the largest roll or pitch on the way [rad]
    attitude_held: tuple[int, ...] = ()  # the axes the package's attitude hold held (3 roll, 4 pitch)

    @property
    def measured(self) -> float:
        return float(self.speed[-1])

    @property
    def ratio(self) -> float:
        return self.measured / self.analytic if self.analytic else math.nan


def open_loop(bench: Bench, axis: int, wrench: float, thrust_n: np.ndarray, net_n: float) -> Response:
    """Hold `thrust_n` [N] (the thrusters' split of `wrench` [N or N m] along `axis`) from rest until
    the speed along the axis settles, with the bench's attitude hold where it has one; the analytic
    speed solves d_l u + d_q u|u| = F with F the wrench, the net buoyancy `net_n` [N] added in heave
    (the vehicle level: body z is the world's)."""
    force = wrench + (net_n if axis == HEAVE else 0.0)
    vehicle = bench.vehicle
    analytic = terminal_speed(
        float(vehicle.linear_damping[axis]), float(vehicle.quadratic_damping[axis]), force
    )
    bench.reset()
    trace = bench.run(thrust_n, RUN_MAX_S, settle=axis, attitude=True)
    settled = trace.time_s[-1] < RUN_MAX_S - SAMPLE_S / 2
    heel_rad = float(np.abs(trace.rpy_rad[:, :2]).max())
    sign = 1 if wrench > 0 else -1
    speed = trace.nu_body[:, axis]
    return Response(axis, sign, trace.time_s, speed, analytic, settled, heel_rad, bench.hold.held)


@dataclass(frozen=True)
class Decay:
    """A release from a heel in roll (k = 0) or pitch (1), thrusters idle: the angle over time
    [rad], its period as measured and as `Hydrostatics.damped_period_s` gives it [s]."""

    k: int
    time_s: np.ndarray
    angle_rad: np.ndarray
    measured_s: float
    analytic_s: float

    @property
    def ratio(self) -> float:
        return self.measured_s / self.analytic_s


def decay(bench: Bench, k: int, statics: Hydrostatics, heel_rad: float = math.radians(10.0)) -> Decay:
    """Release the vehicle from `heel_rad` in roll (k = 0) or pitch (1) and let it swing for six
    of its analytic periods (10 to 60 s)."""
    analytic = statics.damped_period_s(k)
    duration_s = min(max(6.0 * analytic, 10.0), RUN_MAX_S) if math.isfinite(analytic) else RUN_MAX_S
    rpy = [0.0, 0.0, 0.0]
    rpy[k] = heel_rad
    bench.reset((rpy[0], rpy[1], rpy[2]))
    trace = bench.run(np.zeros(len(bench.thrusters.spec.names)), duration_s)
    angle = trace.rpy_rad[:, k]
    return Decay(k, trace.time_s, angle, measured_period_s(trace.time_s, angle), analytic)
