"""A campaign's plots (PNG, matplotlib's Agg, no pyplot state): per figure, its distribution per
scenario and variant (a box over the runs, each run a point); and the pass rate over the
matrix's first two axes as a heat map, every scenario pooled."""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Patch

from abyss.validation.campaign.store import FIGURES

if TYPE_CHECKING:
    from abyss.validation.campaign.case import Case

HEAT_MAP = "pass_rate"  # the heat map's file name, without .png


def figure_names(cases: Sequence[Case]) -> list[str]:
    """The figures the runs have: FIGURES' order, then the others (interventions) sorted."""
    seen = {name for c in cases for r in c.records for name, v in r.figures.items() if v is not None}
    return [n for n in FIGURES if n in seen] + sorted(seen - set(FIGURES))


def plot_figure(name: str, cases: Sequence[Case], path: Path) -> Path | None:
    """One figure's values: per scenario a box per variant with each run's value as a point;
    None (nothing written) where no run has the figure."""
    scenarios = list(dict.fromkeys(c.scenario for c in cases))
    variants = list(dict.fromkeys(c.variant for c in cases))
    colours = [f"C{i % 10}" for i in range(len(variants))]
    fig = Figure(figsize=(max(6.0, 0.6 * len(cases) + 2.0), 4.5), dpi=100)
    ax = fig.add_subplot()
    plotted = False
    for c in cases:
        values = [v for r in c.records if (v := r.figures.get(name)) is not None]
        if not values:
            continue
        j = variants.index(c.variant)
        x = scenarios.index(c.scenario) * (len(variants) + 1) + j
        ax.boxplot([values], positions=[x], widths=0.7, showfliers=False, patch_artist=False)
        offsets = np.linspace(-0.2, 0.2, len(values)) if len(values) > 1 else np.zeros(1)
        ax.plot(x + offsets, values, "o", color=colours[j], markersize=4, alpha=0.8)
        plotted = True
    if not plotted:
        return None
    ax.set_xticks([i * (len(variants) + 1) + (len(variants) - 1) / 2 for i in range(len(scenarios))])
    ax.set_xticklabels(scenarios, rotation=30, ha="right", fontsize=8)
    ax.set_ylabel(name)
    ax.set_title(f"{name} per scenario and variant")
    ax.grid(axis="y", alpha=0.3)
    if len(variants) > 1:
        ax.legend(
            handles=[Patch(color=col, label=v) for v, col in zip(variants, colours, strict=True)], fontsize=7
        )
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    return path


def _key(value: Any) -> str:
    return json.dumps(value, sort_keys=True)


def pass_rates(
    cases: Sequence[Case], axes: tuple[str, str]
) -> tuple[list[Any], list[Any], np.ndarray, np.ndarray]:
    """The values of each axis (in the plan's order) and, per pair, the passes and the runs of
    every scenario pooled: (rows' values, columns' values, passes [rows x columns], runs)."""
    rows = list({_key(c.values[axes[0]]): c.values[axes[0]] for c in cases}.values())
    columns = list({_key(c.values[axes[1]]): c.values[axes[1]] for c in cases}.values())
    passes = np.zeros((len(rows), len(columns)), dtype=int)
    runs = np.zeros_like(passes)
    row_of = {_key(v): i for i, v in enumerate(rows)}
    column_of = {_key(v): i for i, v in enumerate(columns)}
    for c in cases:
        i, j = row_of[_key(c.values[axes[0]])], column_of[_key(c.values[axes[1]])]
        passes[i, j] += c.passes
        runs[i, j] += c.runs
    return rows, columns, passes, runs


def plot_heat_map(cases: Sequence[Case], axes: tuple[str, str], path: Path) -> Path:
    """The pass rate over two matrix axes, every scenario pooled, each cell with passes/runs."""
    rows, columns, passes, runs = pass_rates(cases, axes)
    with np.errstate(invalid="ignore", divide="ignore"):
        rate = np.where(runs > 0, passes / np.maximum(runs, 1), math.nan)
    fig = Figure(figsize=(max(4.0, 1.4 * len(columns) + 2.5), max(3.0, 0.8 * len(rows) + 1.5)), dpi=100)
    ax = fig.add_subplot()
    image = ax.imshow(rate, vmin=0.0, vmax=1.0, cmap="RdYlGn", aspect="auto")
    for i in range(len(rows)):
        for j in range(len(columns)):
            ax.text(
                j,
                i,
                f"{passes[i, j]}/{runs[i, j]}" if runs[i, j] else "-",
                ha="center",
                va="center",
                fontsize=9,
            )
    ax.set_xticks(range(len(columns)), [str(v) for v in columns], fontsize=8)
    ax.set_yticks(range(len(rows)), [str(v) for v in rows], fontsize=8)
    ax.set_xlabel(axes[1])
    ax.set_ylabel(axes[0])
    ax.set_title("pass rate, every scenario pooled")
    fig.colorbar(image, ax=ax, label="pass rate")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    return path


def plot_all(cases: Sequence[Case], axes: tuple[str, ...], plots_dir: Path) -> list[Path]:
    """Every figure's plot, and the heat map where the matrix has two axes or more."""
    written = [
        p for name in figure_names(cases) if (p := plot_figure(name, cases, plots_dir / f"{name}.png"))
    ]
    if len(axes) >= 2:
        written.append(plot_heat_map(cases, (axes[0], axes[1]), plots_dir / f"{HEAT_MAP}.png"))
    return written
