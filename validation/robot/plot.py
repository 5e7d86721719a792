"""`abyss robot check`'s figure (PNG, matplotlib's Agg, no pyplot state): the open-loop speeds
against their analytic terminal speeds, the roll and pitch decays with their periods, and the arm's
reach in front of the vehicle against the stereo pair's field of view, from the side and from above."""

from __future__ import annotations

import math
import textwrap
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

from abyss.description.robot import AXIS_NAMES

if TYPE_CHECKING:
    from abyss.validation.robot.geometry import Workspace
    from abyss.validation.robot.report import Report

RAY_REACH = 1.3  # the field of view's edges drawn this far, of the farthest tool point from the cameras


def plot(report: Report, path: Path) -> Path:
    """The figure of `report`, written to `path`."""
    fig = Figure(figsize=(15, 9), dpi=100)
    axes = fig.subplots(2, 3)
    _speeds(axes[0, 0], report, linear=True)
    _speeds(axes[0, 1], report, linear=False)
    _decays(axes[0, 2], report)
    _workspace(axes[1, 0], report.workspace, (0, 2), "side (x ahead, z up) [m]")
    _workspace(axes[1, 1], report.workspace, (0, 1), "above (x ahead, y left) [m]")
    _verdict(axes[1, 2], report)
    fig.suptitle(f"abyss robot check: {report.robot}")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    return path


def _speeds(ax: Axes, report: Report, linear: bool) -> None:
    """The open-loop runs (translations, or yaw): speed over time, the analytic terminal dashed."""
    runs = [r for r in report.responses if (r.axis < 3) == linear]
    for i, r in enumerate(runs):
        colour = f"C{i % 10}"
        label = f"{AXIS_NAMES[r.axis]} {'+' if r.sign > 0 else '-'} ({r.ratio:.3f} of analytic)"
        ax.plot(r.time_s, r.speed, color=colour, linewidth=1.4, label=label)
        ax.axhline(r.analytic, color=colour, linestyle="--", linewidth=0.9)
    ax.set_xlabel("time from rest [s]")
    ax.set_ylabel("speed [m/s]" if linear else "yaw rate [rad/s]")
    ax.set_title("open loop: " + ("translations" if linear else "yaw") + " (dashed: analytic)", fontsize=10)
    ax.grid(alpha=0.3)
    if runs:
        ax.legend(fontsize=7)


def _decays(ax: Axes, report: Report) -> None:
    for d in report.decays:
        axis = ("roll", "pitch")[d.k]
        label = f"{axis}: period {d.measured_s:.3f} s, analytic {d.analytic_s:.3f} s"
        ax.plot(d.time_s, np.degrees(d.angle_rad), linewidth=1.3, label=label)
    ax.axhline(0.0, color="0.5", linewidth=0.6)
    ax.set_xlabel("time from release [s]")
    ax.set_ylabel("angle [deg]")
    ax.set_title("free decay from 10 deg", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)


def _workspace(ax: Axes, space: Workspace, plane: tuple[int, int], title: str) -> None:
    """The tool points in one plane of the vehicle's frame: seen and unseen of those in front,
    the rest faint; the hull's outline; each stereo camera's field of view, out past the reach."""
    i, j = plane
    points = space.points_m_body
    behind = ~space.ahead
    seen, unseen = space.ahead & space.seen, space.ahead & ~space.seen
    ax.scatter(points[behind, i], points[behind, j], s=2, color="0.75", label="elsewhere")
    ax.scatter(points[unseen, i], points[unseen, j], s=4, color="C1", label="in front, unseen")
    ax.scatter(points[seen, i], points[seen, j], s=4, color="C2", label="in front, seen by both")
    low, high = space.outline_m_body
    ax.add_patch(Rectangle((low[i], low[j]), high[i] - low[i], high[j] - low[j], fill=False, color="k"))
    for centre, corners in zip(space.cameras_m_body, space.corners_m_body, strict=True):
        ray_m = RAY_REACH * float(np.linalg.norm(points - centre, axis=1).max())
        for corner in corners:
            end = centre + ray_m * (corner - centre) / np.linalg.norm(corner - centre)
            ax.plot([centre[i], end[i]], [centre[j], end[j]], color="C0", linewidth=0.7)
    share = space.share_seen
    shown = f"{100 * share:.0f}%" if math.isfinite(share) else "none in front"
    ax.set_title(f"reach and stereo view, {title}: {shown} seen", fontsize=10)
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="lower left")


def _verdict(ax: Axes, report: Report) -> None:
    ax.axis("off")
    warned = [r for r in report.rows if r.status == "warn"]
    lines = ["every check passes"] if not warned else [f"{len(warned)} row(s) warn:"]
    lines += [textwrap.shorten(f"  {r.check}: {r.name}: {r.figures}", 64, placeholder=" ...") for r in warned]
    lines.append(f"{len(report.rows)} rows, {report.runtime_s:.1f} s; the table: report.txt")
    ax.text(0.0, 1.0, "\n".join(lines), va="top", ha="left", family="monospace", fontsize=8)
