"""`abyss robot check DIR`: what a team reads before it trusts a robot package. The package is
loaded as every station loads it (description.robot.load_robot: a broken one raises ConfigError naming
the file and the field), then held to six checks, each a few rows of figures against a bound:

1. kinematics: MuJoCo and Pinocchio agree on the arm's frames (geometry.frame_agreement);
2. hydrostatics: weight against buoyancy, the centres, the righting moment and the roll and
   pitch periods it gives (physics.hydrostatics);
3. allocation: the axes the thrusters move and the largest wrench along each, a linear program
   (geometry.axis_limits);
4. open loop: that wrench held from rest in the simulation's marine model until the speed
   settles, against the terminal speed of the damping, roll and pitch held by the package's own
   attitude hold where its configuration sets one (simulation.attitude_kp/kd), and the roll and
   pitch free decays against their periods (physics.open_loop, decay);
5. published: the figures the package's `[published]` table carries against the simulated ones;
6. workspace: the share of the arm's reach in front of the vehicle its stereo pair sees
   (geometry.workspace).

A row passes, warns, or is n/a (nothing to hold: no published figures). `check_robot` returns the
`Report`; `write` leaves its table (report.txt, report.json) and its figure (robot-check.png,
plot.py) in a directory."""

from __future__ import annotations

import dataclasses
import json
import math
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from abyss.config import load
from abyss.config.simulation import SimulationConfig
from abyss.description.robot import (
    AXIS_NAMES,
    COMMANDED_AXES,
    Robot,
    load_robot,
)
from abyss.description.robot_file import PUBLISHED_FIGURES
from abyss.stations.simulation.attitude import ROLL, AttitudeHold
from abyss.validation.robot import physics
from abyss.validation.robot.geometry import AxisLimit, Workspace, axis_limits, frame_agreement, workspace
from abyss.validation.robot.report import CHECKS, Report, Row, Status

SEED = 0  # the arm's configurations, the vehicle's poses: the same report every time
FRAME_TOLERANCE = 1e-6  # [m] and [rad]: two double-precision readings of one chain agree to ~1e-12
NET_BUOYANCY_SHARE = 0.02  # of the weight: more than a small trim weight or float fixes
NEEDED_AXES = (0, 2, 5)  # surge, heave, yaw: what the vehicle controller cannot fly without
SPEED_BOUND = 0.10  # terminal speeds, simulated / analytic (see `response_row`)
HEEL_BOUND_RAD = math.radians(15.0)  # the most roll or pitch an open-loop run may reach (ditto)
PERIOD_BOUND = 0.05  # decay periods, simulated / analytic (see `_decay_rows`)
SEEN_SHARE = 0.10  # the least share of the reach in front that the stereo pair must see
# the bound on simulated / published of each figure a `[published]` table may hold (description.robot's
# PUBLISHED_FIGURES says what each means). Speeds and bollard pulls are trials' figures (a tether,
# the surface, rounding): 25%; a mass in air is weighed: 10%.
PUBLISHED_BOUNDS = {name: 0.10 if name == "mass_kg" else 0.25 for name in PUBLISHED_FIGURES}
UNITS = {0: "m/s", 1: "m/s", 2: "m/s", 5: "rad/s"}
WRENCH_UNITS = {0: "N", 1: "N", 2: "N", 5: "N m"}


def check_robot(directory: Path, progress: Callable[[str], None] = lambda _: None) -> Report:
    """The six checks on the package in `directory` (see the module's text); `progress` is told
    each check's name as it starts. ConfigError for a package that does not load."""
    started = time.monotonic()
    robot = load_robot(Path(directory))
    rng = np.random.default_rng(SEED)
    rows: list[Row] = []
    progress(CHECKS[0])
    rows += _kinematics_rows(robot, rng)
    progress(CHECKS[1])
    bench = bench_of(robot)
    statics = physics.hydrostatics(bench)
    rows += _hydrostatics_rows(statics)
    progress(CHECKS[2])
    spec = robot.spec.thrusters
    limits = axis_limits(robot.allocation, robot.actuated_axes, spec.forward_max_n, spec.reverse_max_n)
    rows += _allocation_rows(robot, limits)
    progress(CHECKS[3])
    responses = [physics.open_loop(bench, a.axis, a.wrench, a.thrust_n, statics.net_n) for a in limits]
    decays = [physics.decay(bench, k, statics) for k in (0, 1)]
    held = _held(bench.hold)
    rows += [response_row(r, held) for r in responses] + _decay_rows(decays, statics)
    progress(CHECKS[4])
    rows += published_rows(robot, statics, responses, limits)
    progress(CHECKS[5])
    size = SimulationConfig()
    space = workspace(robot, rng, size.camera_width_px, size.camera_height_px)
    rows.append(_workspace_row(space, size))
    elapsed_s = time.monotonic() - started
    return Report(
        robot.name,
        robot.directory,
        tuple(rows),
        statics,
        tuple(limits),
        tuple(responses),
        tuple(decays),
        space,
        elapsed_s,
    )


def bench_of(robot: Robot) -> physics.Bench:
    """The robot's bench with the attitude hold its package flies with: the configuration's
    simulation.attitude_kp/kd, the package's [config] over the defaults (config.load), as
    the simulation's low level reads them; none held where they are zero."""
    flown = load(None, [f"simulation.robot={robot.directory}"]).simulation
    return physics.Bench(robot, flown.attitude_kp, flown.attitude_kd)


def _status(ok: bool) -> Status:
    return "pass" if ok else "warn"


def _kinematics_rows(robot: Robot, rng: np.random.Generator) -> list[Row]:
    found = frame_agreement(robot, rng)
    ok = found.distance_m <= FRAME_TOLERANCE and found.angle_rad <= FRAME_TOLERANCE
    return [
        Row(
            "kinematics",
            "arm frames",
            f"{found.distance_m:.1e} m ({found.worst}), {found.angle_rad:.1e} rad",
            f"<= {FRAME_TOLERANCE:.0e} m, rad",
            _status(ok),
            f"MuJoCo and Pinocchio on {found.frames} frames (joints' origins and axes, the end effector) "
            f"at {found.configurations} seeded random poses: the onboard IK sees the arm the physics moves",
        )
    ]


def _hydrostatics_rows(h: physics.Hydrostatics) -> list[Row]:
    share = h.net_n / h.weight_n
    bg = h.bg_m
    righting = h.righting_nm_per_rad > 0
    cg, cb = h.gravity_m_body, h.buoyancy_m_body
    rows = [
        Row(
            "hydrostatics",
            "net buoyancy",
            f"{h.net_n:+.3g} N ({100 * share:+.2f}% of the weight {h.weight_n:.5g} N)",
            f"|net| <= {100 * NET_BUOYANCY_SHARE:.0f}% of weight",
            _status(abs(share) <= NET_BUOYANCY_SHARE),
            "buoyancy (hull and arm's links) less weight, stowed: > 0 floats up; the thrusters "
            "hold whatever is left, for the whole dive",
        ),
        Row(
            "hydrostatics",
            "BG",
            f"({bg[0]:+.3f}, {bg[1]:+.3f}, {bg[2]:+.3f}) m: CG ({cg[0]:+.3f}, {cg[1]:+.3f}, {cg[2]:+.3f}), "
            f"CB ({cb[0]:+.3f}, {cb[1]:+.3f}, {cb[2]:+.3f})",
            "BG_z > 0",
            _status(righting),
            "the centre of buoyancy above that of gravity rights the vehicle; at or below it, it capsizes",
        ),
        Row(
            "hydrostatics",
            "righting moment",
            f"W BG_z = {h.righting_nm_per_rad:.4g} N m/rad (roll and pitch)",
            "> 0",
            _status(righting),
            "the moment per radian of heel that levels the vehicle, the stiffness of its roll and pitch",
        ),
    ]
    for k, axis in enumerate(("roll", "pitch")):
        rows.append(
            Row(
                "hydrostatics",
                f"{axis} period",
                f"{h.period_s(k):.2f} s (I {h.rigid_inertia[k]:.4g} + A {h.added_inertia[k]:.4g}, "
                f"{h.effective_inertia[k]:.4g} kg m^2 with the other axes free)",
                "finite",
                _status(math.isfinite(h.period_s(k))),
                "2 pi sqrt(I_eff / (W BG_z)), undamped: the rigid inertia about the origin and the "
                "added, less what the sway or surge it couples to takes",
            )
        )
    return rows


def _allocation_rows(robot: Robot, limits: list[AxisLimit]) -> list[Row]:
    moved = [AXIS_NAMES[a] for a in robot.actuated_axes]
    missing = [AXIS_NAMES[a] for a in NEEDED_AXES if a not in robot.actuated_axes]
    unmoved = [AXIS_NAMES[a] for a in COMMANDED_AXES if a not in robot.actuated_axes]
    why = "the thrusters move every axis the vehicle controller commands"
    if unmoved:
        why = f"{', '.join(unmoved)} not moved" + (": the vehicle controller needs it" if missing else "")
    rows = [
        Row(
            "allocation",
            "actuated axes",
            f"{', '.join(moved)} ({len(robot.thrusters)} thrusters)",
            ", ".join(AXIS_NAMES[a] for a in NEEDED_AXES),
            _status(not missing),
            why,
        )
    ]
    for axis in robot.actuated_axes:
        ways = {a.sign: a.wrench for a in limits if a.axis == axis}
        rows.append(
            Row(
                "allocation",
                AXIS_NAMES[axis],
                f"{ways[1]:+.0f} / {ways[-1]:+.0f} {WRENCH_UNITS[axis]}",
                "> 0 each way",
                _status(ways[1] > 0 > ways[-1]),
                "a linear program: the largest wrench each way with the other actuated axes at zero "
                "and each thruster within -reverse_max..forward_max",
            )
        )
    return rows


def _held(hold: AttitudeHold) -> str:
    """What the open-loop rows say of the package's attitude hold: "" where it holds nothing."""
    if not hold.held:
        return ""
    axes = " and ".join(("roll", "pitch")[a - ROLL] for a in hold.held)
    kp, kd = ", ".join(f"{g:g}" for g in hold.kp), ", ".join(f"{g:g}" for g in hold.kd)
    return f"; {axes} held by the package's attitude hold (kp {kp} N m/rad, kd {kd} N m s/rad), as it flies"


def response_row(r: physics.Response, held: str = "") -> Row:
    """Within SPEED_BOUND: the analytic speed takes the axis alone, the run has what it leaves out
    (the pitch or roll the thrust's line of action gives, C_RB and C_A's coupling, the rotors' lag
    and the arm's mass): under 1% on a vehicle near neutral and level; 10% still catches a thrust
    the model's motors cap below robot.toml's, or a damping read in the wrong units. And within
    HEEL_BOUND_RAD: the analytic speed is the level vehicle's, and roll and pitch are left to the
    righting moment (description.robot.COMMANDED_AXES), or to the package's attitude hold where its
    configuration has one (`held` says so: as the simulation's low level flies it), so a vehicle
    that heels further under full thrust (the thrust's moment about the centre of gravity, the
    added mass's Munk moment, against W BG_z and the hold) flies heeled, or tumbles, under the
    station's controller too."""
    unit = UNITS[r.axis]
    name = f"{AXIS_NAMES[r.axis]} {'+' if r.sign > 0 else '-'}"
    ok = r.settled and abs(r.ratio - 1.0) <= SPEED_BOUND and r.heel_rad <= HEEL_BOUND_RAD
    steady = f"at {r.time_s[-1]:.1f} s" if r.settled else f"not steady at {r.time_s[-1]:.0f} s"
    return Row(
        "open loop",
        name,
        f"{r.measured:+.3f} {unit} {steady}; analytic {r.analytic:+.3f} {unit}; ratio {r.ratio:.3f}; "
        f"heel {math.degrees(r.heel_rad):.1f} deg",
        f"ratio {1 - SPEED_BOUND:.2f}..{1 + SPEED_BOUND:.2f}, heel <= {math.degrees(HEEL_BOUND_RAD):.0f} deg",
        _status(ok),
        "full thrust from rest in the marine model until steady, against d_l u + d_q u|u| = F" + held,
    )


def _decay_rows(decays: list[physics.Decay], h: physics.Hydrostatics) -> list[Row]:
    """Within PERIOD_BOUND: the analytic period leaves out the quadratic damping and the free axes'
    damping (under 1%); 5% catches an inertia or a righting arm 10% off in the simulation."""
    rows = []
    for d in decays:
        axis = ("roll", "pitch")[d.k]
        ok = math.isfinite(d.analytic_s) and abs(d.ratio - 1.0) <= PERIOD_BOUND
        reason = "W BG_z <= 0" if h.righting_nm_per_rad <= 0 else "overdamped"
        figures = f"{d.measured_s:.3f} s; no analytic period: {reason}"
        if math.isfinite(d.analytic_s):
            stiffness = h.righting_nm_per_rad * h.effective_inertia[d.k]
            zeta = h.linear_damping[d.k] / (2.0 * math.sqrt(stiffness))
            figures = (
                f"{d.measured_s:.3f} s; analytic {d.analytic_s:.3f} s (zeta {zeta:.2f}); ratio {d.ratio:.3f}"
            )
        rows.append(
            Row(
                "open loop",
                f"{axis} decay",
                figures,
                f"ratio {1 - PERIOD_BOUND:.2f}..{1 + PERIOD_BOUND:.2f}",
                _status(ok),
                f"released from 10 deg of {axis}: its period against hydrostatics' damped by the linear term",
            )
        )
    return rows


def _workspace_row(space: Workspace, size: SimulationConfig) -> Row:
    ahead = int(space.ahead.sum())
    share = space.share_seen
    return Row(
        "workspace",
        "stereo sees the reach",
        f"{100 * share:.0f}% of {ahead} tool points in front ({len(space.ahead)} sampled)",
        f">= {100 * SEEN_SHARE:.0f}%",
        _status(math.isfinite(share) and share >= SEEN_SHARE),
        "in front: beyond the stereo pair, within the hull's outline across; seen: in both cameras' "
        f"{size.camera_width_px}x{size.camera_height_px} images (the MJCF's fovy)",
    )


def _simulated(
    h: physics.Hydrostatics, responses: list[physics.Response], limits: list[AxisLimit]
) -> dict[str, float]:
    """The figures a `[published]` table may name, as the checks found them (PUBLISHED_FIGURES)."""
    speed = {(r.axis, r.sign): abs(r.measured) for r in responses}
    wrench = {(a.axis, a.sign): abs(a.wrench) for a in limits}
    found = {"mass_kg": h.mass_kg}
    for axis, name in ((0, "surge"), (1, "sway"), (2, "heave")):
        for sign, way in ((1, ""), (-1, "_reverse")):
            if (axis, sign) in speed:
                found[f"{name}{way}_max_mps"] = speed[axis, sign]
        if (axis, 1) in wrench:
            found[f"bollard_{('forward', 'lateral', 'vertical')[axis]}_n"] = wrench[axis, 1]
    if (5, 1) in speed:
        found["yaw_max_degps"] = math.degrees(min(speed[5, 1], speed[5, -1]))
    return found


def published_rows(
    robot: Robot, h: physics.Hydrostatics, responses: list[physics.Response], limits: list[AxisLimit]
) -> list[Row]:
    """A row per figure of robot.toml's `[published]` table (description.robot has refused a name it
    does not know, or a figure that is no positive number, at load): the simulated one over it."""
    table = dict(robot.spec.published)
    source = str(table.pop("source", "")) or "no source given"
    if not table:
        return [
            Row("published", "figures", "none carried", "-", "n/a", "robot.toml has no [published] figures")
        ]
    simulated = _simulated(h, responses, limits)
    rows = []
    for key, value in table.items():
        if key not in simulated:
            figures, bound, ok = f"{value!r}", "a figure of an axis the thrusters move", False
        else:
            ratio, share = simulated[key] / float(value), PUBLISHED_BOUNDS[key]
            figures = (
                f"{simulated[key]:.3g} simulated against {float(value):.3g} published; ratio {ratio:.2f}"
            )
            bound, ok = f"ratio {1 - share:.2f}..{1 + share:.2f}", abs(ratio - 1.0) <= share
        rows.append(Row("published", key, figures, bound, _status(ok), f"{PUBLISHED_FIGURES[key]}; {source}"))
    return rows


def write(report: Report, out: Path) -> list[Path]:
    """report.txt (the table), report.json (its rows) and robot-check.png (plot.py) in `out`."""
    from abyss.validation.robot.plot import plot

    out.mkdir(parents=True, exist_ok=True)
    text, table = out / "report.txt", out / "report.json"
    text.write_text(report.text() + "\n")
    document = {
        "robot": report.robot,
        "directory": str(report.directory),
        "passed": report.passed,
        "runtime_s": report.runtime_s,
        "rows": [dataclasses.asdict(r) for r in report.rows],
    }
    table.write_text(json.dumps(document, indent=2) + "\n")
    return [text, table, plot(report, out / "robot-check.png")]
