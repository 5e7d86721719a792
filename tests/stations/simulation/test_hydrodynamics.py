"""The Fossen model against an independent integration of the same equations (SciPy), the
thrusters' rotor model, the marine models and the current."""

from __future__ import annotations

import shutil
from pathlib import Path

import mujoco
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from abyss.common.errors import ConfigError
from abyss.description.marine import VehicleModel
from abyss.description.robot import ROBOTS_DIR, load_robot, robot_at, thrust_matrix
from abyss.stations.simulation.hydrodynamics import Fossen
from abyss.stations.simulation.marine import Current
from abyss.stations.simulation.thrusters import Thrusters

ROBOT = robot_at("")  # the shipped robot package


BLUEROV2 = ROBOTS_DIR / "bluerov2_heavy_alpha5"  # the BlueROV2 Heavy's package (with a Reach Alpha 5)
DT_S = 0.002


def bluerov2_marine() -> VehicleModel:
    """Its marine model: the published coefficients, as its package loads them."""
    return load_robot(BLUEROV2).marine


def bluerov2_vehicle() -> mujoco.MjModel:
    """The BlueROV2 Heavy alone, as its coefficients were identified: the package's MJCF without
    the arm and the trim ballast it carries for the sea, in fresh water."""
    spec = mujoco.MjSpec.from_file(str(BLUEROV2 / "robot.xml"))
    for body in ("arm_base", "ballast"):  # the arm's actuators and exclusions go with it
        spec.delete(spec.body(body))
    spec.option.timestep = DT_S
    spec.option.density, spec.option.viscosity = 1000.0, 0.0011
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    return spec.compile()


def skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def quat_to_rotation(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


class Reference:
    """Fossen's equations for one rigid vehicle, written from the book (2021: eq. 3.44 M_RB,
    3.64 C_RB, 6.44 C_A, 4.6 g) in the body frame (FLU, z up), state (p_world, q_wxyz, nu)."""

    def __init__(self, model: mujoco.MjModel, vehicle: VehicleModel) -> None:
        b = model.body("vehicle").id
        self.m = float(model.body_mass[b])
        self.r_g = model.body_ipos[b].copy()
        inertia_cg = np.diag(model.body_inertia[b])  # the MJCF's principal axes are the body's here
        assert np.allclose(model.body_iquat[b], [1, 0, 0, 0])
        i_o = inertia_cg - self.m * skew(self.r_g) @ skew(self.r_g)
        self.i_o = i_o
        self.m_rb = np.block([[self.m * np.eye(3), -self.m * skew(self.r_g)], [self.m * skew(self.r_g), i_o]])
        self.v = vehicle
        self.g = -float(model.opt.gravity[2])
        self.buoyancy_n = float(model.opt.density) * self.g * vehicle.volume_m3
        self.mass_inv = np.linalg.inv(self.m_rb + vehicle.added_mass)

    def derivative(self, _t: float, x: np.ndarray, tau_body: np.ndarray) -> np.ndarray:
        q, nu = x[3:7], x[7:]
        rotation = quat_to_rotation(q)
        v1, w = nu[:3], nu[3:]
        c_rb = np.block(
            [
                [self.m * skew(w), -self.m * skew(w) @ skew(self.r_g)],
                [self.m * skew(self.r_g) @ skew(w), -skew(self.i_o @ w)],
            ]
        )
        a = self.v.added_mass @ nu
        c_a = np.block([[np.zeros((3, 3)), -skew(a[:3])], [-skew(a[:3]), -skew(a[3:])]])
        d = np.diag(self.v.linear_damping + self.v.quadratic_damping * np.abs(nu))
        weight = rotation.T @ np.array([0.0, 0.0, -self.m * self.g])
        lift = rotation.T @ np.array([0.0, 0.0, self.buoyancy_n])
        g_eta = np.r_[
            weight + lift, np.cross(self.r_g, weight) + np.cross(self.v.centre_of_buoyancy_m_body, lift)
        ]
        nu_dot = self.mass_inv @ (tau_body + g_eta - c_rb @ nu - c_a @ nu - d @ nu)
        w_, x_, y_, z_ = q
        q_dot = 0.5 * np.array(
            [
                -x_ * w[0] - y_ * w[1] - z_ * w[2],
                w_ * w[0] + y_ * w[2] - z_ * w[1],
                w_ * w[1] + z_ * w[0] - x_ * w[2],
                w_ * w[2] + x_ * w[1] - y_ * w[0],
            ]
        )
        return np.r_[rotation @ v1, q_dot, nu_dot]


def simulate_mujoco(tau_body: np.ndarray, duration_s: float) -> np.ndarray:
    """The BlueROV2 in MuJoCo with the Fossen model and a body wrench [N, N m] about its origin:
    (t, x, y, z, yaw, u, v, w, r) sampled every 0.1 s."""
    model = bluerov2_vehicle()
    data = mujoco.MjData(model)
    fossen = Fossen(model, bluerov2_marine())
    rows = []
    steps = round(duration_s / DT_S)
    for k in range(steps + 1):
        if k % 50 == 0:
            rows.append(_sample(data.time, data.qpos[:3], data.qpos[3:7], data.qvel[:6]))
        mujoco.mj_step1(model, data)
        fossen.apply(model, data, np.zeros(3))
        rotation = data.xmat[1].reshape(3, 3)
        data.qfrc_applied[:3] += rotation @ tau_body[:3]
        data.qfrc_applied[3:6] += tau_body[3:]
        mujoco.mj_step2(model, data)
    return np.array(rows)


def simulate_reference(tau_body: np.ndarray, duration_s: float) -> np.ndarray:
    model = bluerov2_vehicle()
    reference = Reference(model, bluerov2_marine())
    x0 = np.r_[0.0, 0.0, -5.0, 1.0, 0.0, 0.0, 0.0, np.zeros(6)]
    times = np.arange(0.0, duration_s + 1e-9, 0.1)
    solution = solve_ivp(
        reference.derivative,
        (0.0, duration_s),
        x0,
        t_eval=times,
        args=(tau_body,),
        rtol=1e-9,
        atol=1e-11,
        method="DOP853",
    )
    assert solution.success
    return np.array(
        [
            _sample(t, x[:3], x[3:7], np.r_[quat_to_rotation(x[3:7]) @ x[7:10], x[10:]])
            for t, x in zip(solution.t, solution.y.T, strict=True)
        ]
    )


def _sample(t: float, position: np.ndarray, quat: np.ndarray, qvel: np.ndarray) -> list[float]:
    """qvel as MuJoCo's free joint has it: linear in the world, angular in the body."""
    rotation = quat_to_rotation(np.asarray(quat))
    yaw = np.arctan2(rotation[1, 0], rotation[0, 0])
    return [t, *position, yaw, *(rotation.T @ qvel[:3]), qvel[5]]


MANOEUVRES = {  # body wrench [N, N m]: steps from rest, held 10 s
    "surge": np.array([60.0, 0, 0, 0, 0, 0]),
    "heave": np.array([0, 0, 40.0, 0, 0, 0]),
    "yaw": np.array([0, 0, 0, 0, 0, 3.0]),
    "combined": np.array([50.0, 15.0, -20.0, 0.3, -0.4, 2.0]),
}


@pytest.mark.parametrize("manoeuvre", MANOEUVRES)
def test_fossen_in_mujoco_follows_the_equations_integrated_by_scipy(manoeuvre: str) -> None:
    """Position, heading and velocities within 2 % of each one's range over the run."""
    ours = simulate_mujoco(MANOEUVRES[manoeuvre], 10.0)
    reference = simulate_reference(MANOEUVRES[manoeuvre], 10.0)
    assert ours.shape == reference.shape
    columns = ("x", "y", "z", "yaw", "u", "v", "w", "r")
    moved = [c for c in range(1, 9) if np.ptp(reference[:, c]) > 0.05]
    assert moved, "the manoeuvre should move the vehicle"
    for c in moved:
        error = np.max(np.abs(ours[:, c] - reference[:, c])) / np.ptp(reference[:, c])
        assert error < 0.02, f"{manoeuvre}: {columns[c - 1]} off by {error:.1%} of its range"


def test_terminal_surge_speed_at_full_thrust_is_the_published_vehicles() -> None:
    """Full surge on the four vectored T200s, laid out as ArduSub's vectored frame drives them (the
    front pair in reverse, at its published 40.2 N, the rear pair matching it: the allocation keeps
    the wrench's direction), against the published surge damping: X = 141 u|u| + 13.7 u solved for
    u. The vehicle is held level, as ArduSub holds
    it with its vertical thrusters (a stiff PD on roll and pitch stands in for that here): its
    centre of gravity is 1 cm below that of buoyancy, too little to hold the Munk moment at speed."""
    model = bluerov2_vehicle()
    data = mujoco.MjData(model)
    vehicle = bluerov2_marine()
    allocation = thrust_matrix(model, "vehicle", vehicle.thrusters.names)
    fossen, thrusters = Fossen(model, vehicle), Thrusters(model, vehicle.thrusters, allocation)
    thrust = thrusters.allocate(np.array([1e4, 0, 0, 0, 0, 0]))  # more than it has: scaled to its limit
    assert np.max(np.abs(thrust)) == pytest.approx(vehicle.thrusters.reverse_max_n)
    assert list(np.sign(thrust[:4])) == [-1, -1, 1, 1]  # front left and right astern, the rear ahead
    surge_n = float((thrusters.allocation @ thrust)[0])
    for k in range(round(30.0 / DT_S)):
        if k % 5 == 0:
            thrusters.apply(data, thrust, 5 * DT_S)
        mujoco.mj_step1(model, data)
        fossen.apply(model, data, np.zeros(3))
        w, x, y, _ = data.qpos[3:7]
        roll, pitch = 2.0 * (w * x), 2.0 * (w * y)  # small angles
        data.qfrc_applied[3:5] += -50.0 * np.array([roll, pitch]) - 10.0 * data.qvel[3:5]
        mujoco.mj_step2(model, data)
    u = float((data.xmat[1].reshape(3, 3).T @ data.qvel[:3])[0])
    a, b = vehicle.quadratic_damping[0], vehicle.linear_damping[0]
    expected = (-b + np.sqrt(b * b + 4 * a * surge_n)) / (2 * a)
    assert surge_n == pytest.approx(4 * 40.2 / np.sqrt(2), rel=1e-3)
    assert u == pytest.approx(expected, rel=0.02)


def test_the_added_mass_is_in_the_inertia() -> None:
    """A step of force from rest: the first acceleration is (M_RB + M_A)^-1 tau, about F / (m +
    X_udot), not F / m."""
    model = bluerov2_vehicle()
    data = mujoco.MjData(model)
    vehicle = bluerov2_marine()
    fossen = Fossen(model, vehicle)
    mujoco.mj_step1(model, data)
    fossen.apply(model, data, np.zeros(3))
    data.qfrc_applied[0] += 100.0
    mujoco.mj_step2(model, data)
    at_rest = np.r_[0.0, 0.0, -5.0, 1.0, np.zeros(9)]
    expected = Reference(model, vehicle).derivative(0.0, at_rest, np.r_[100.0, np.zeros(5)])[7:]
    assert data.qacc[:6] == pytest.approx(expected, rel=1e-6, abs=1e-9)
    assert data.qacc[0] < 0.75 * 100.0 / 13.5


def test_thruster_rotor_lag_dead_band_and_asymmetric_curve() -> None:
    model = bluerov2_vehicle()
    data = mujoco.MjData(model)
    spec = bluerov2_marine().thrusters
    thrusters = Thrusters(model, spec, thrust_matrix(model, "vehicle", spec.names))
    n = len(spec.names)
    thrusters.drive(data, np.full(n, 0.9 * spec.deadband), 1.0)  # inside the dead band: nothing
    assert np.all(data.ctrl[thrusters.actuators] == 0.0)
    dt = 0.001
    speeds = []
    for _ in range(round(3 * spec.time_constant_s / dt)):
        thrusters.drive(data, np.ones(n), dt)
        speeds.append(thrusters.rotor_speed[0])
    reached = np.argmax(np.array(speeds) >= 1.0 - np.exp(-1.0)) + 1  # 63 %
    assert reached * dt == pytest.approx(spec.time_constant_s, abs=2 * dt)
    for _ in range(round(20 * spec.time_constant_s / dt)):
        thrusters.drive(data, np.r_[1.0, -1.0, np.zeros(n - 2)], dt)
    assert data.ctrl[thrusters.actuators[0]] == pytest.approx(spec.forward_max_n, rel=1e-6)
    assert data.ctrl[thrusters.actuators[1]] == pytest.approx(-spec.reverse_max_n, rel=1e-6)
    # the allocation steps over the dead band: a small thrust asked for is delivered
    for _ in range(round(20 * spec.time_constant_s / dt)):
        thrusters.apply(data, np.full(n, 0.5), dt)
    assert np.allclose(data.ctrl[thrusters.actuators], 0.5, rtol=1e-6)


def test_a_robot_package_with_a_bad_marine_field_fails_naming_the_file_and_field(tmp_path: Path) -> None:
    text = ROBOT.file.read_text()
    for old, new, field in (
        ("volume_m3 = 2.916", "volume_m3 = -1", "buoyancy.volume_m3"),
        ("deadband = 0.05", "deadband = 0.9", "thrusters.deadband"),
        ("linear = [86.6, ", "linear = [", "damping.linear"),
        ("time_constant_s = 0.2\n", "", "thrusters.time_constant_s"),
        # a misspelt field is refused by its name, with the fields there are (a misspelt `diagonal`
        # said `added_mass.matrix: needs 36 numbers`)
        ("diagonal = [", "diagnoal = [", "added_mass.diagnoal"),
        ("[damping]\n", "[damping]\ncubic = [0, 0, 0, 0, 0, 0]\n", "damping.cubic"),
    ):
        assert old in text
        package = tmp_path / field
        shutil.copytree(ROBOT.directory, package)
        bad = package / "robot.toml"
        bad.write_text(text.replace(old, new))
        with pytest.raises(ConfigError) as error:
            load_robot(package)
        assert error.value.field == field and str(bad) in str(error.value)
        if field in ("added_mass.diagnoal", "damping.cubic"):  # with the fields there are
            assert "not a field of [" in error.value.reason
            assert "diagonal (6 numbers" in error.value.reason or "linear (6 numbers" in error.value.reason


def test_both_shipped_marine_models_load() -> None:
    for directory in (ROBOT.directory, BLUEROV2):
        vehicle = load_robot(directory).marine
        assert vehicle.source and vehicle.added_mass.shape == (6, 6)


def test_current_profile_and_gauss_markov_process() -> None:
    profile = ((-10.0, 0.1, 0.0, 0.0), (0.0, 0.5, 0.2, 0.0))
    still = Current(profile, 0.0, 60.0, np.random.default_rng(0))
    assert np.allclose(still.velocity_mps_world(-5.0), [0.3, 0.1, 0.0])
    assert np.allclose(still.velocity_mps_world(-20.0), [0.1, 0.0, 0.0])  # held beyond the ends
    sigma, tau = 0.1, 5.0
    current = Current((), sigma, tau, np.random.default_rng(1))
    samples = []
    for k in range(1, 20001):
        current.advance(k * 0.5)
        samples.append(current.velocity_mps_world(-8.0)[:2])
    x = np.array(samples)
    assert np.std(x[:, 0]) == pytest.approx(sigma, rel=0.15)
    lag = round(tau / 0.5)  # correlation e^-1 at one time constant
    correlation = np.corrcoef(x[:-lag, 0], x[lag:, 0])[0, 1]
    assert correlation == pytest.approx(np.exp(-1.0), abs=0.08)
    repeat = Current((), sigma, tau, np.random.default_rng(1))
    repeat.advance(0.5)
    assert np.allclose(repeat.velocity_mps_world(-8.0)[:2], x[0])


def test_the_diagonal_added_masss_fast_path_is_the_general_equations() -> None:
    """Fossen.apply on Python floats for a diagonal M_A gives the force and inertia of the
    general path (wrench_n_body and the 6x6 products), turning, moving and in a current."""
    model = bluerov2_vehicle()
    vehicle = bluerov2_marine()
    fast, general = Fossen(model, vehicle), Fossen(model, vehicle)
    general.diagonal = None  # the matrix path, as a vehicle with off-diagonal terms takes
    assert fast.diagonal is not None
    data = mujoco.MjData(model)
    data.qpos[3:7] = np.array([0.9, 0.1, -0.2, 0.3]) / np.linalg.norm([0.9, 0.1, -0.2, 0.3])
    data.qvel[:6] = [0.4, -0.3, 0.2, 0.1, -0.15, 0.25]
    current = np.array([0.2, -0.1, 0.05])
    results = []
    for fossen in (fast, general):
        mujoco.mj_step1(model, data)
        fossen.apply(model, data, current)
        results.append((data.qfrc_applied[:6].copy(), data.M.copy()))
    (f_fast, m_fast), (f_general, m_general) = results
    assert f_fast == pytest.approx(f_general, rel=1e-12, abs=1e-9)
    assert m_fast == pytest.approx(m_general, rel=1e-12, abs=1e-9)
    assert np.abs(f_fast).max() > 1.0  # the state moves the water: a force to compare
