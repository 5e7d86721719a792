"""`abyss`: the command line. It parses arguments and calls the testbed; each command group
lives in a module of its own (`system`, `link`, `lab`, `operator`, `validation`, `campaign`, `models`,
`robot`, `sitl`)."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from abyss.cli import campaign, export, lab, link, models, operator, record, robot, sitl, system, validation
from abyss.cli.args import NoSystem
from abyss.common.errors import AbyssError, BusError

DESCRIPTION = (
    "abyss: a testbed for deep-sea ROV software: the vehicle, its onboard computer, the support "
    "vessel and the shore station over Zenoh, every hop through an emulated link"
)


def parser() -> argparse.ArgumentParser:
    root = argparse.ArgumentParser(prog="abyss", description=DESCRIPTION)
    sub = root.add_subparsers(dest="command", required=True)
    for group in (system, link, lab, operator, record, export, validation, campaign, models, robot, sitl):
        group.add_commands(sub)
    return root


def main(argv: list[str] | None = None) -> int:
    args: Any = parser().parse_args(argv)
    if getattr(args, "func", None) is models.cmd_scene_export and not args.format:
        args.format = ["bt", "ply"]
    try:
        return int(args.func(args))
    except BusError as exc:  # a tool's session (abyss op's, teleop's) that found no system to join
        shown = NoSystem(args.connect, args.system) if getattr(args, "talks_to_system", False) else exc
        print(f"abyss: {shown}", file=sys.stderr)
        return 2
    except AbyssError as exc:
        print(f"abyss: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
