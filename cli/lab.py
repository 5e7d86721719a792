"""`abyss lab up | exec | down`: the whole system as four network namespaces on this machine."""

from __future__ import annotations

import argparse
import dataclasses
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

from abyss.cli.args import config_args, cpu_arg, load_config
from abyss.common.errors import LinkError
from abyss.interface import keys
from abyss.linkemu.control import LINK_MODES


def cmd_lab_up(args: argparse.Namespace) -> int:
    from abyss.launch.lab import Lab, LabPlacement
    from abyss.launch.up import run_up

    config = load_config(args)
    if not any(s.startswith("onshore.viewer=") for s in args.set):  # no display inside a namespace
        config = dataclasses.replace(config, onshore=dataclasses.replace(config.onshore, viewer="save"))
    lab = Lab(args.name).make()
    placement = LabPlacement(lab, args.link)
    shapers: list[subprocess.Popen[bytes]] = []
    try:
        print(
            f"abyss: lab {lab.name!r}: namespaces {', '.join(lab.netns(s) for s in keys.STATIONS)}; "
            f"a command on a station's host: abyss lab exec STATION -- CMD",
            flush=True,
        )
        profiles = {hop: getattr(config.links, hop) for hop in keys.HOPS}
        for station in args.external:
            for command in placement.shape_for(station, profiles):
                shapers.append(subprocess.Popen(command, stdin=subprocess.DEVNULL))
        lab.enter("onshore")  # the supervisor watches from shore's host, as an operator would
        return run_up(
            config, args.out, args.duration, args.keep_running, 0, args.external, args.restart, placement
        )
    finally:
        for shaper in shapers:
            shaper.terminate()
            shaper.wait(timeout=10)
        lab.remove()


def cmd_lab_exec(args: argparse.Namespace) -> int:
    from abyss.launch.lab import Lab

    command = list(args.command)
    if command[:1] == ["--name"] and len(command) > 1:  # after STATION, where argparse's remainder begins
        args.name, command = command[1], command[2:]
    command = command[1:] if command[:1] == ["--"] else command
    lab = Lab(args.name)
    if lab.netns(args.station) not in lab.existing():
        raise LinkError(f"no lab {lab.name!r} on this machine: start one with `sudo abyss lab up`")
    if not command:
        raise LinkError("nothing to run: abyss lab exec STATION -- COMMAND [ARGS...]")
    sys.stdout.flush()
    os.execvp("ip", ["ip", "netns", "exec", lab.netns(args.station), *command])


def cmd_lab_down(args: argparse.Namespace) -> int:
    from abyss.launch.lab import Lab

    print(f"abyss: {Lab(args.name).down()}")
    return 0


def add_commands(sub: Any) -> None:
    lab = sub.add_parser("lab", help="the whole system as four network namespaces (root)").add_subparsers(
        dest="lab", required=True
    )
    p = lab.add_parser("up", help="namespaces, shaped hops, the mission; removed at the end")
    config_args(p)
    cpu_arg(p)
    p.add_argument("--name", default="lab", help="lab name: namespaces abyss-NAME-STATION (default lab)")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    p.add_argument("--keep-running", action="store_true", help="stay up after the mission ends")
    p.add_argument("--out", type=Path, help="run directory (default runs/<system>-<time>)")
    p.add_argument(
        "--link",
        choices=LINK_MODES,
        default="auto",
        help="how each station shapes its hops (default auto: netem, else tun)",
    )
    p.add_argument(
        "--external",
        action="append",
        default=[],
        choices=keys.STATIONS,
        metavar="STATION",
        help="do not start this station: run yours in its namespace (abyss lab exec); "
        "its hops are shaped by `abyss link shape` there",
    )
    p.add_argument("--restart", action="store_true", help="start a station that dies again")
    p.set_defaults(func=cmd_lab_up)
    p = lab.add_parser("exec", help="run a command on a station's host (its namespace)")
    p.add_argument("station", choices=keys.STATIONS)
    p.add_argument("--name", default="lab")
    p.add_argument("command", nargs=argparse.REMAINDER, metavar="-- COMMAND")
    p.set_defaults(func=cmd_lab_exec)
    p = lab.add_parser("down", help="stop a lab's run and remove its namespaces (also a killed run's)")
    p.add_argument("--name", default="lab")
    p.set_defaults(func=cmd_lab_down)
