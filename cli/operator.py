"""`abyss op | teleop | fault`: the operator's tools."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import zenoh

from abyss.bus import description
from abyss.bus.session import message_of
from abyss.cli.args import client, connect_args
from abyss.common.errors import BadInput, ConfigError
from abyss.description.robot import robot_at
from abyss.description.site import site_at
from abyss.interface import faults, keys
from abyss.interface.messages import (
    SimulationControl,
    SimulationStatus,
    encode,
)


def fault_control(fault: str, target: str, value: float, names: faults.ModelNames) -> SimulationControl:
    """The message of `abyss fault`, checked against the fault table and the running robot's and
    panel's parts (`names`: the running system's description) as the simulation checks it;
    ConfigError with the allowed targets or the value's range."""
    if not faults.row(fault).targets and target:
        raise ConfigError("fault target", f"{fault} takes no target (got {target!r})")
    try:
        faults.check(fault, target, value, names)
        return SimulationControl(fault, target, value)
    except BadInput as exc:
        raise ConfigError("fault", exc.reason) from None


def fault_help() -> str:
    """`abyss fault`'s description: the fault table, each fault's targets on the shipped robot and
    site (a running system's own are what a fault is checked against when it is sent)."""
    names = faults.model_names(robot_at("").spec, site_at("").panel)
    lines = [
        "Faults (interface/faults.py), each with its targets on the shipped robot and site (those of",
        "the running system, which it describes, are what a fault is checked against):",
    ]
    for row in faults.FAULT_TABLE.values():
        allowed = faults.targets(row.name, names)
        where = f"targets: {', '.join(allowed)}; " if allowed else ""
        lines += [f"  {row.line()}", f"      {where}value: {row.value_range()}"]
    return "\n".join(lines)


FAULT_TABLE = "(the fault table)"  # `abyss fault`'s description, made when its help is shown


class FaultTableHelp(argparse.RawDescriptionHelpFormatter):
    """`abyss fault`'s help, its fault table made when the help is shown: it compiles the shipped
    robot's model, which every other command would pay for, and which would import MuJoCo into
    `abyss`'s own process before a command that renders has chosen its OpenGL backend."""

    def add_text(self, text: str | None) -> None:
        super().add_text(fault_help() if text == FAULT_TABLE else text)


def cmd_fault(args: argparse.Namespace) -> int:
    session = client(args)
    seen: list[SimulationStatus] = []

    def on_status(sample: zenoh.Sample) -> None:
        message = message_of(sample, SimulationStatus)
        if message is not None:
            seen.append(message)

    try:
        running = description.fetch(session, args.system)
        control = fault_control(args.fault, args.target, args.value, running.model_names)
        subscriber = session.declare_subscriber(keys.simulation_status_key(args.system), on_status)
        session.put(keys.simulation_control_key(args.system), encode(control, 0, time.time()))
        deadline = time.monotonic() + 3.0
        while time.monotonic() < deadline and len(seen) < 2:  # the first may predate the fault
            time.sleep(0.05)
        subscriber.undeclare()
    finally:
        session.close()
    if not seen:
        print(f"abyss: sent, but no simulation of system {args.system} reported", file=sys.stderr)
        return 1
    print(f"faults now: {seen[-1].faults or 'none'}")
    return 0


def cmd_teleop(args: argparse.Namespace) -> int:
    from abyss.console.teleop import run_teleop

    if not 0 < args.step_m <= 1.0 or not 0 < args.step_deg <= 45.0:
        raise ConfigError("teleop", "--step-m must lie in (0, 1] m and --step-deg in (0, 45] deg")
    return run_teleop(args.connect, args.system, args.step_m, args.step_deg, args.joystick)


def cmd_op(args: argparse.Namespace) -> int:
    from abyss.console.op import run_op

    return run_op(args.connect, args.system, args.command, args.value, args.timeout, args.turn or args.to)


def cmd_console(args: argparse.Namespace) -> int:
    from abyss.console.server import run_console

    if args.token:
        from abyss.common.errors import ConfigError
        from abyss.console.access import token_of
        from abyss.security.access import tool_certificates

        certificates = tool_certificates(args.connect)
        if certificates is None:
            raise ConfigError("--token", "only a console on a tls/ endpoint has a token to work out again")
        print(token_of(certificates, args.system))
        return 0
    return run_console(args.connect, args.system, args.port, args.bind, args.viewer_url)


def add_commands(sub: Any) -> None:
    p = sub.add_parser("teleop", help="drive the vehicle or the end-effector from a joystick or the keyboard")
    connect_args(p)
    p.add_argument("--step-m", type=float, default=0.1, help="goal step per key [m] (joystick: m/s)")
    p.add_argument("--step-deg", type=float, default=5.0, help="goal step per key [deg] (joystick: deg/s)")
    p.add_argument(
        "--joystick",
        type=Path,
        metavar="DEVICE",
        help="Linux joystick device (default /dev/input/js0 when present; else the keyboard)",
    )
    p.set_defaults(func=cmd_teleop)

    p = sub.add_parser(
        "console",
        help="the pilot's console: a web page on this machine to fly the mission from (docs/console.md)",
    )
    p.add_argument("--port", type=int, default=0, help="the page's port (default: any free one)")
    p.add_argument(
        "--bind",
        default="127.0.0.1",
        metavar="ADDRESS",
        help="where the page is served (default 127.0.0.1; any other address asks for the operator's token)",
    )
    p.add_argument("--viewer-url", default="", help="rerun's web viewer of the run, to embed in the page")
    p.add_argument(
        "--token",
        action="store_true",
        help="print the token of a console on this tls/ endpoint (from $ABYSS_TLS_DIR's operator key)",
    )
    connect_args(p)
    p.set_defaults(func=cmd_console)

    p = sub.add_parser("op", help="send one operator command through shore and print onboard's answer")
    p.add_argument("command", choices=("waypoints", "arm", "mode", "valve", "lever"))
    p.add_argument(
        "value",
        metavar="VALUE",
        help="waypoints: 'x,y,z,yaw; ...' [m, rad]; arm: 'x,y,z,roll,pitch,yaw' [m, rad]; "
        "mode: hold|auto|teleop; valve: a valve's name (the running site's: valve_0..2 on the shipped "
        "one) with --turn; lever: a lever's name (lever_0, lever_1) with --to",
    )
    p.add_argument("--turn", metavar="DEG", default="", help="valve: the angle to turn it by [deg]")
    p.add_argument("--to", choices=("up", "down"), default="", help="lever: the stop to throw it to")
    connect_args(p)
    p.add_argument("--timeout", type=float, default=15.0, metavar="S", help="wait this long for the answer")
    p.set_defaults(func=cmd_op)

    p = sub.add_parser(
        "fault",
        help="inject a fault into a running simulation",
        description=FAULT_TABLE,
        formatter_class=FaultTableHelp,
    )
    p.add_argument("fault", choices=faults.fault_names())
    p.add_argument("target", nargs="?", default="", help="the part it acts on (below, by fault)")
    p.add_argument("value", nargs="?", type=float, default=0.0, help="its setting (below, by fault)")
    connect_args(p)
    p.set_defaults(func=cmd_fault)
