"""The vessel's map in a hybrid run against the all-simulated run it replays (docs/hybrid.md):
shore's final octree of each run (`scene.msgpack`, read as tests/e2e/test_hybrid.py reads it),
its occupied cells seen from above (x-y) and from the side (x-z), one run's over the other's,
the cells with no cell of the other run within one cell marked. Precision: the share of the
hybrid's cells with one of the original's within one cell (its 26 neighbours); recall: the share
of the original's with one of the hybrid's.

Run: .venv/bin/python bench/hybrid_figure.py ORIGINAL_RUN HYBRID_RUN [--out PNG] [--dpi N]
(the original: an all-simulated `abyss up --record all`; the hybrid: its rerun with
`abyss up --hybrid nav,joints` and tests/e2e/vehicle.py replaying it as the vehicle). Prints the
figures and writes the PNG (docs/images/hybrid_map.png by default)."""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt
from matplotlib.axes import Axes
from matplotlib.colors import ListedColormap
from matplotlib.patches import Patch

from abyss.interface.messages import SceneUpdate, decode
from abyss.scene.export import SCENE_FILE
from abyss.scene.receiver import SceneReceiver

ROOT = Path(__file__).resolve().parents[1]
Cell = tuple[int, int, int]
NEAR: tuple[Cell, ...] = tuple((i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1))
# what a projected cell shows, in order: the later drawn over the earlier where one projects onto another
KINDS: tuple[tuple[str, str], ...] = (
    ("all-simulated only", "tab:blue"),
    ("hybrid only", "tab:orange"),
    ("both", "0.75"),
    ("all-simulated, nothing of the hybrid's within a cell", "black"),
    ("hybrid, nothing of the all-simulated's within a cell", "red"),
)


def occupied(run_dir: Path) -> tuple[set[Cell], float]:
    """Shore's final map of a run: its occupied cells' integer keys, and the cell size [m]."""
    receiver = SceneReceiver()
    receiver.apply(decode("scene", (run_dir / SCENE_FILE).read_bytes(), SceneUpdate).message)
    centres = receiver.occupied_cells()[0]
    size_m = receiver.resolution_m
    return {(int(x), int(y), int(z)) for x, y, z in np.floor(centres / size_m)}, size_m


def unmatched(mine: set[Cell], theirs: set[Cell]) -> set[Cell]:
    """The cells of `mine` with no cell of `theirs` within one cell."""
    return {(x, y, z) for x, y, z in mine if not any((x + i, y + j, z + k) in theirs for i, j, k in NEAR)}


def view(ax: Axes, layers: tuple[set[Cell], ...], axes: tuple[int, int], size_m: float) -> None:
    """One projection onto two axes (0 x, 1 y, 2 z): each projected cell coloured by the last of
    `layers` (in KINDS' order) with a cell projecting onto it."""
    projected = [{(c[axes[0]], c[axes[1]]) for c in cells} for cells in layers]
    every = np.array(sorted(set().union(*projected)), dtype=int).reshape(-1, 2)
    lo, hi = every.min(axis=0), every.max(axis=0)
    image = np.full((hi[1] - lo[1] + 1, hi[0] - lo[0] + 1), -1, dtype=int)
    for kind, cells in enumerate(projected):
        for u, v in cells:
            image[v - lo[1], u - lo[0]] = kind
    colours = ListedColormap(["white", *(colour for _, colour in KINDS)])
    extent = (lo[0] * size_m, (hi[0] + 1) * size_m, lo[1] * size_m, (hi[1] + 1) * size_m)
    ax.imshow(
        image + 1,
        cmap=colours,
        vmin=0,
        vmax=len(KINDS),
        origin="lower",
        extent=extent,
        interpolation="nearest",
    )
    names = "xyz"
    ax.set_xlabel(f"{names[axes[0]]} [m, world]")
    ax.set_ylabel(f"{names[axes[1]]} [m, world]")
    ax.grid(True, linewidth=0.3)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("original", type=Path, help="the all-simulated run's directory")
    p.add_argument("hybrid", type=Path, help="the hybrid rerun's directory")
    p.add_argument("--out", type=Path, default=ROOT / "docs" / "images" / "hybrid_map.png")
    p.add_argument("--dpi", type=int, default=100)
    args = p.parse_args()
    original, size_m = occupied(args.original)
    hybrid, hybrid_size_m = occupied(args.hybrid)
    if hybrid_size_m != size_m:
        raise SystemExit(f"the maps' cells differ: {size_m:g} m and {hybrid_size_m:g} m")
    hybrid_only, original_only = unmatched(hybrid, original), unmatched(original, hybrid)
    precision = 1.0 - len(hybrid_only) / len(hybrid)
    recall = 1.0 - len(original_only) / len(original)
    print(
        f"{len(hybrid)} cells of the hybrid's against {len(original)} of the original's "
        f"({size_m:g} m); within one cell: precision {precision:.3f} ({len(hybrid_only)} of the "
        f"hybrid's without), recall {recall:.3f} ({len(original_only)} of the original's without)"
    )
    both = hybrid & original
    layers = (original - both, hybrid - both, both, original_only, hybrid_only)
    fig, (top, side) = plt.subplots(
        2, 1, figsize=(7.2, 8.4), sharex=True, gridspec_kw={"height_ratios": (3.2, 1.0)}
    )
    view(top, layers, (0, 1), size_m)
    top.set_title("from above (x-y)")
    top.set_xlabel("")
    view(side, layers, (0, 2), size_m)
    side.set_title("from the side (x-z)")
    counts = (len(original - both), len(hybrid - both), len(both), len(original_only), len(hybrid_only))
    fig.legend(
        handles=[
            Patch(color=colour, label=f"{name} ({n})")
            for (name, colour), n in zip(KINDS, counts, strict=True)
        ],
        loc="lower center",
        ncol=2,
        fontsize=8,
        title=f"cells of {size_m:g} m: the all-simulated run's {len(original)}, the hybrid's {len(hybrid)}",
        title_fontsize=8,
    )
    fig.suptitle(
        "The vessel's map, the hybrid rerun against the all-simulated run:\n"
        f"precision {precision:.2f}, recall {recall:.2f} within one {size_m:g} m cell"
    )
    fig.tight_layout(rect=(0.0, 0.1, 1.0, 1.0))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=args.dpi)
    print(f"wrote {args.out} ({args.out.stat().st_size / 1e3:.0f} kB)")


if __name__ == "__main__":
    main()
