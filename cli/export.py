"""`abyss export mcap`: a recorded run as one MCAP file in the ROS 2 profile."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any


def cmd_export_mcap(args: argparse.Namespace) -> int:
    from abyss.ros2.mcap import DEFAULT_NAME, export_mcap

    out = args.output or args.run_dir / DEFAULT_NAME
    print(f"abyss: exporting the recording of {args.run_dir} to {out} ...", flush=True)
    summary = export_mcap(
        args.run_dir,
        out,
        lambda done, total: print(
            f"abyss: {done / total:4.0%} ({done} of {total} recorded messages)", flush=True
        ),
    )
    skipped = sum(summary["skipped"].values())
    print(
        f"abyss: wrote {out}: {summary['messages']} messages on {len(summary['topics'])} topics, "
        f"{summary['bytes'] / 1e6:.1f} MB, {summary['run_s']:.0f} s of run in {summary['export_s']:.1f} s"
        + (f"; {skipped} messages did not convert (logged)" if skipped else "")
    )
    return 0


def add_commands(sub: Any) -> None:
    export = sub.add_parser("export", help="a recorded run in another format").add_subparsers(
        dest="export", required=True
    )
    p = export.add_parser(
        "mcap",
        help="one MCAP file in the ROS 2 profile (standard types, REP 103/105 frames) for Foxglove, "
        "rerun, ros2 bag",
    )
    p.add_argument("run_dir", type=Path, metavar="RUN_DIR", help="the run directory of an `abyss up`")
    p.add_argument(
        "-o", "--output", type=Path, metavar="FILE", help="the MCAP file (default: RUN_DIR/run.mcap)"
    )
    p.set_defaults(func=cmd_export_mcap)
