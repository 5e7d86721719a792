"""`abyss robot check DIR`: the report a team reads before trusting a robot package
(validation/robot/check.py). Exit 0 when every check passes, 1 when any warns, 2 for a package
that does not load (its ConfigError, naming the file and the field, through cli's handler)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any


def cmd_robot_check(args: argparse.Namespace) -> int:
    from abyss.validation.robot.check import check_robot, write
    from abyss.validation.robot.report import CHECKS

    def progress(name: str) -> None:
        print(f"abyss: robot check {CHECKS.index(name) + 1}/{len(CHECKS)}: {name} ...", flush=True)

    report = check_robot(args.directory, progress)
    print(report.text())
    written = write(report, args.out)
    print(f"abyss: wrote {', '.join(p.name for p in written)} in {args.out.resolve()}")
    return 0 if report.passed else 1


def add_commands(sub: Any) -> None:
    robot = sub.add_parser("robot", help="robot packages").add_subparsers(dest="robot", required=True)
    p = robot.add_parser(
        "check",
        help="hold a robot package to its kinematics, hydrostatics, thrust, open-loop responses, "
        "published figures and cameras' view of its arm (exit 0: all pass, 1: a warning, 2: broken)",
    )
    p.add_argument("directory", type=Path, metavar="DIR", help="the package: robot.toml and its model")
    p.add_argument(
        "--out",
        type=Path,
        default=Path("robot-check"),
        metavar="DIR",
        help="where the table and the figure go (default: robot-check/ here)",
    )
    p.set_defaults(func=cmd_robot_check)
