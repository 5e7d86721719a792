"""`abyss plot RUN_DIR`: the four figures of the original paper from a run's control record:
the vehicle's position error (x, y, z) and heading error over its waypoints, and the
end-effector's position error (x, y, z) and orientation error for its constant target; and,
for a run with interventions, a fifth: each worked part's true angle against its target, with
the intervention's phases, over the grip's squeeze and the fingers' true contact force."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from abyss.common.errors import ConfigError
from abyss.launch.control_record import CONTROL_FILE, read_control, read_panel
from abyss.launch.verdict import read_json

AXES = ("x", "y", "z")
FIGURES = ("vehicle_position_error", "vehicle_heading_error", "ee_position_error", "ee_orientation_error")
INTERVENTION_FIGURE = "intervention"


def _figure(
    time_s: np.ndarray,
    series: dict[str, np.ndarray],
    ylabel: str,
    title: str,
    path: Path,
    marks_s: np.ndarray,
    holds: np.ndarray,
) -> None:
    fig, ax = plt.subplots(figsize=(8, 4.5), dpi=100)
    for label, values in series.items():
        ax.plot(time_s, values, label=label, linewidth=1.4)
    for t in marks_s:
        ax.axvline(t, color="0.6", linestyle=":", linewidth=1)
    if holds.any():  # failsafe periods, shaded
        ax.fill_between(
            time_s,
            0,
            1,
            where=holds,
            transform=ax.get_xaxis_transform(),
            color="tab:red",
            alpha=0.12,
            label="failsafe: holding",
        )
    ax.axhline(0.0, color="0.3", linewidth=0.8)
    ax.set_xlabel("simulated time [s]")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper right")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def plot_run(run_dir: Path) -> list[str]:
    """Write the four PNG files into `run_dir`; return the lines to print."""
    if not (run_dir / CONTROL_FILE).is_file():
        raise ConfigError("RUN_DIR", f"{run_dir} has no {CONTROL_FILE}; give a run directory of `abyss up`")
    c = read_control(run_dir)
    if len(c["sim_time_s"]) < 2:
        raise ConfigError("RUN_DIR", f"{run_dir / CONTROL_FILE} holds fewer than two rows")
    holds = c["failsafe"] != ""
    _vehicle_figures(run_dir, c, holds)
    arm = np.isin(c["arm_mode"], ("moving", "reached"))
    _arm_figures(run_dir, c, holds, arm)
    return _final_lines(run_dir, c, holds, arm) + _intervention_figure(run_dir, c)


def _vehicle_figures(run_dir: Path, c: dict[str, np.ndarray], holds: np.ndarray) -> None:
    """The vehicle's position and heading errors while it has a goal; dotted: each waypoint reached."""
    t = c["sim_time_s"]
    reached_s = t[1:][np.diff(c["waypoint_index"]) > 0]  # when each waypoint was reached
    vehicle = c["mode"] != "idle"
    _figure(
        t[vehicle],
        {f"e_{a}": c[f"error_{a}_m"][vehicle] for a in AXES},
        "position error [m]",
        "Vehicle position error, waypoints (dotted: each reached)",
        run_dir / f"{FIGURES[0]}.png",
        reached_s,
        holds[vehicle],
    )
    _figure(
        t[vehicle],
        {"e_psi": np.degrees(c["heading_error_rad"][vehicle])},
        "heading error [deg]",
        "Vehicle heading error",
        run_dir / f"{FIGURES[1]}.png",
        reached_s,
        holds[vehicle],
    )


def _arm_figures(run_dir: Path, c: dict[str, np.ndarray], holds: np.ndarray, arm: np.ndarray) -> None:
    """The end-effector's position and orientation errors while the arm has a goal."""
    t = c["sim_time_s"]
    arm_t = t[arm] if arm.any() else t[:0]
    _figure(
        arm_t,
        {f"e_{a}": c[f"ee_error_{a}_m"][arm] * 1e3 for a in AXES},
        "position error [mm]",
        "End-effector position error, constant target",
        run_dir / f"{FIGURES[2]}.png",
        np.array([]),
        holds[arm],
    )
    _figure(
        arm_t,
        {"angle": np.degrees(c["ee_orientation_error_rad"][arm])},
        "orientation error [deg]",
        "End-effector orientation error, constant target",
        run_dir / f"{FIGURES[3]}.png",
        np.array([]),
        holds[arm],
    )


def _final_lines(run_dir: Path, c: dict[str, np.ndarray], holds: np.ndarray, arm: np.ndarray) -> list[str]:
    """What was written, and the final errors."""
    last = -1
    vehicle_mm = [c[f"error_{a}_m"][last] * 1e3 for a in AXES]
    lines = [
        f"wrote {', '.join(name + '.png' for name in FIGURES)} in {run_dir}",
        f"final errors at t = {c['sim_time_s'][last]:.1f} s: vehicle {_mm(vehicle_mm)}, heading "
        f"{math.degrees(c['heading_error_rad'][last]):+.2f} deg",
    ]
    if arm.any():
        ee_mm = [c[f"ee_error_{a}_m"][arm][last] * 1e3 for a in AXES]
        lines.append(
            f"final errors, end-effector: {_mm(ee_mm)}, orientation "
            f"{math.degrees(c['ee_orientation_error_rad'][arm][last]):.2f} deg"
        )
    else:
        lines.append("the arm never moved towards a goal in this run")
    lines.append(
        f"failsafe: {int(c['failsafe_events'][last])} events, {holds.mean():.0%} of the record holding"
    )
    return lines


def _intervention_figure(run_dir: Path, c: dict[str, np.ndarray]) -> list[str]:
    """The parts the interventions worked: true angle against target, phases, grip and contact."""
    panel = read_panel(run_dir)
    worked = [p for p in dict.fromkeys(c["intervention_target"]) if p]
    if panel is None or not worked or len(panel["sim_time_s"]) < 2:
        return []
    targets = {i["part"]: i for i in read_json(run_dir / "summary.json").get("interventions", [])}
    fig, (top, bottom) = plt.subplots(
        2, 1, figsize=(8, 6.5), dpi=100, sharex=True, gridspec_kw={"height_ratios": [3, 2]}
    )
    lines = [
        _plot_part(top, bottom, panel, part, f"C{i}", targets.get(part)) for i, part in enumerate(worked)
    ]
    _mark_phases(top, c)
    bottom.plot(
        c["sim_time_s"], c["gripper_force_n"], color="k", linewidth=1.2, label="grip squeeze (onboard)"
    )
    top.set_ylabel("angle [deg]")
    top.set_title("Interventions: each part's angle against its target (dotted: the phases)")
    bottom.set_ylabel("force [N]")
    bottom.set_xlabel("simulated time [s]")
    for ax in (top, bottom):
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper left", fontsize=7)
    fig.tight_layout()
    fig.savefig(run_dir / f"{INTERVENTION_FIGURE}.png")
    plt.close(fig)
    return [f"wrote {INTERVENTION_FIGURE}.png: " + "; ".join(lines)]


def _plot_part(
    top: Any, bottom: Any, panel: dict[str, np.ndarray], part: str, color: str, target: dict[str, Any] | None
) -> str:
    """One worked part: its true angle (and target) above, the fingers' force on it below; the
    line that says where it ended."""
    t_panel = panel["sim_time_s"]
    top.plot(t_panel, np.degrees(panel[f"{part}_rad"]), color=color, linewidth=1.4, label=f"{part} (truth)")
    bottom.plot(
        t_panel,
        panel[f"{part}_finger_force_n"],
        color=color,
        linewidth=1.0,
        alpha=0.7,
        label=f"fingers on {part} (truth)",
    )
    final_deg = math.degrees(panel[f"{part}_rad"][-1])
    if target is None:
        return f"{part}: {final_deg:+.1f} deg"
    top.axhline(
        target["target_deg"],
        color=color,
        linestyle="--",
        linewidth=1,
        label=f"{part} target +- {target['tolerance_deg']:g} deg",
    )
    return (
        f"{part}: {final_deg:+.1f} deg, target {target['target_deg']:+.1f} deg "
        f"({'success' if target['success'] else 'NOT DONE'})"
    )


def _mark_phases(top: Any, c: dict[str, np.ndarray]) -> None:
    """A dotted line, named, where each intervention phase begins."""
    t = c["sim_time_s"]
    phase = np.char.add(np.char.add(c["intervention_target"], " "), c["intervention_phase"])
    changes = np.flatnonzero(phase[1:] != phase[:-1]) + 1
    for k in changes:
        if c["intervention_phase"][k]:
            top.axvline(t[k], color="0.6", linestyle=":", linewidth=1)
            top.text(
                t[k],
                1.0,
                c["intervention_phase"][k],
                rotation=90,
                fontsize=7,
                va="top",
                ha="right",
                transform=top.get_xaxis_transform(),
                color="0.35",
            )


def _mm(values_mm: list[float]) -> str:
    parts = ", ".join(f"{a} {v:+.2f}" for a, v in zip(AXES, values_mm, strict=True))
    return f"{math.hypot(*values_mm):.2f} mm ({parts} mm)"
