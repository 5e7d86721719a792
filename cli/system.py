"""`abyss up | station | health | certs | keys`: running stations and whole systems."""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from abyss.cli.args import (
    client,
    config_args,
    connect_args,
    cpu_arg,
    load_config,
    pairs,
)
from abyss.common.errors import ConfigError
from abyss.config import Config, site_of
from abyss.config.hybrid import ROS2_VEHICLE
from abyss.config.stations import VIEWERS, Viewer
from abyss.config.system import RECORD_LEVELS, ROS2_STATIONS
from abyss.interface import keys
from abyss.linkemu.control import LINK_MODES
from abyss.security.access import TLS_DIR_ENV


def cmd_up(args: argparse.Namespace) -> int:
    from abyss.launch.up import run_up

    if args.duration is not None and not 0 < args.duration <= 1e6:
        raise ConfigError("--duration", f"{args.duration:g} s: a positive number of seconds, at most 1e6")
    config = up_config(args, load_config(args))
    if (
        config.hybrid.on
        and config.mission.interventions
        and not any(s.startswith("mission.interventions=") for s in args.set)
    ):
        print(
            "abyss: warning: a hybrid run keeps the mission's interventions "
            f"({', '.join(part for part, _ in config.mission.interventions)}): the real arm grasps the "
            "real panel's parts where --site-pose registers the site; without them, set "
            "mission.interventions=[]",
            file=sys.stderr,
        )
    return run_up(
        config,
        args.out,
        args.duration,
        args.keep_running,
        args.port,
        args.external,
        args.restart,
        console_port=console_port(args.console),
    )


def console_port(text: str) -> int | None:
    """--console PORT|none: the pilot's console's port (0: any free one), None for none."""
    if text == "none":
        return None
    if not text.isdigit() or int(text) > 65535:
        raise ConfigError("--console", f"{text!r} is not a port (0: any free one) or none")
    return int(text)


def up_config(args: argparse.Namespace, config: Config) -> Config:
    """`--viewer` (default: spawn with a display, else save) and `--record` on top of `config`."""
    if args.viewer is not None or not any(s.startswith("onshore.viewer=") for s in args.set):
        viewer: Viewer = args.viewer or (
            "spawn" if os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY") else "save"
        )
        config = dataclasses.replace(config, onshore=dataclasses.replace(config.onshore, viewer=viewer))
    if args.record is not None:
        config = dataclasses.replace(config, record=dataclasses.replace(config.record, level=args.record))
    ros2 = {
        name: value
        for name, value in (
            ("station", getattr(args, "ros2", None)),
            ("domain", getattr(args, "ros_domain", None)),
            ("namespace", getattr(args, "ros_namespace", None)),
        )
        if value is not None
    }
    if ros2:
        if "station" not in ros2 and not config.ros2.station:
            raise ConfigError("--ros-domain/--ros-namespace", "need --ros2 STATION")
        hybrid = config.hybrid
        if ros2.get("station") == "simulation" and not hybrid.on:  # the node is a real vehicle
            hybrid = dataclasses.replace(hybrid, vehicle=ROS2_VEHICLE)
        config = dataclasses.replace(config, ros2=dataclasses.replace(config.ros2, **ros2), hybrid=hybrid)
    return config


def run_args(p: argparse.ArgumentParser, speed: bool = True) -> None:
    """What `abyss up` and `abyss replay` share: configuration, duration, run directory, viewer,
    recording (`speed`: config_args's)."""
    config_args(p, speed)
    cpu_arg(p)
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    p.add_argument("--keep-running", action="store_true", help="stay up after the mission ends")
    p.add_argument("--out", type=Path, help="run directory (default runs/<system>-<time>)")
    p.add_argument("--port", type=int, help=f"public Zenoh port (default {7447} if free; 0: any)")
    p.add_argument(
        "--viewer",
        choices=VIEWERS,
        help="save: runs/<id>/onshore.rrd (the default without a display); web: rerun's web "
        "viewer on a local port; spawn: the native viewer (the default with a display); "
        "none",
    )
    p.add_argument(
        "--record",
        choices=RECORD_LEVELS,
        help="the bus recording in RUN_DIR/record: all (the default): every key, images, clouds "
        "and scene capped at record.bulk_max_rate_hz; control: what is not bulk; none",
    )


def cmd_station(args: argparse.Namespace) -> int:
    from abyss.common.leave import leave
    from abyss.launch.station import configure_logging, run_station, station_main

    configure_logging(args.verbose)
    peers = dict(pairs("--peer", args.peer))
    for hop in peers:
        keys.check_hop(hop)
    config = load_config(args)
    entry = None
    if args.replay is not None:
        from abyss.recording.replay import replayer

        entry = replayer(args.replay, args.speed)
    port = console_port(args.console)
    if port is not None:
        if args.name != "onshore":
            raise ConfigError(
                "--console", f"the pilot's console is served by the onshore station, not {args.name}"
            )
        entry = _with_console(entry or station_main(args.name, config), port)
    code = run_station(
        args.name,
        config,
        args.listen,
        args.connect,
        args.status_file,
        args.link,
        args.zenoh_mode,
        args.tls,
        peers,
        entry,
    )
    leave(code)  # everything is closed and written


def _with_console(entry: Callable[[Config, Any], None], port: int) -> Callable[[Config, Any], None]:
    """The onshore station with the pilot's console served on its own session."""

    def run(config: Config, bus: Any) -> None:
        from abyss.console.server import Console

        console = Console(bus.session, config.system, port, site_of(config).panel)
        print(f"abyss: the pilot's console at {console.url}", flush=True)
        try:
            entry(config, bus)
        finally:
            console.close()

    return run


def cmd_health(args: argparse.Namespace) -> int:
    session = client(args)
    try:
        token = keys.alive_key(args.system, args.station)
        alive = list(session.liveliness().get(token, timeout=args.timeout))
    finally:
        session.close()
    if not any(reply.ok is not None for reply in alive):
        print(
            f"abyss: {args.station} of system {args.system} is not alive at {args.connect}", file=sys.stderr
        )
        return 1
    print(f"{args.station} alive")
    return 0


def cmd_certs_make(args: argparse.Namespace) -> int:
    from abyss.security import certs

    hosts: dict[str, list[str]] = {}
    for holder, host in pairs("--host", args.host):
        if holder not in certs.HOLDERS:
            raise ConfigError("--host", f"unknown holder {holder!r}; allowed: {', '.join(certs.HOLDERS)}")
        hosts.setdefault(holder, []).append(host)
    written = certs.make(args.directory, hosts)
    print(
        f"abyss: wrote {len(written)} files to {args.directory}: ca.pem (give it to every host), "
        f"and <holder>.pem/.key for {', '.join(certs.HOLDERS)}; keep ca.key offline"
    )
    return 0


def cmd_keys(args: argparse.Namespace) -> int:
    """The key table; with a hybrid configuration (--hybrid, or --config a run's config.json),
    who provides each key in that run."""
    hybrid = load_config(args).hybrid
    print(keys.keys_table(hybrid.providers() if hybrid.on else None))
    return 0


def add_commands(sub: Any) -> None:
    _add_up(sub)
    _add_station(sub)
    _add_health(sub)
    _add_certs(sub)
    p = sub.add_parser("keys", help="print the table of every key (and who provides it in a hybrid run)")
    config_args(p, speed=False)
    p.set_defaults(func=cmd_keys)


def _add_up(sub: Any) -> None:
    p = sub.add_parser("up", help="run all four stations on this machine")
    run_args(p)
    p.add_argument(
        "--external",
        action="append",
        default=[],
        choices=keys.STATIONS,
        metavar="STATION",
        help="do not start this station: wait for yours (a real component) on its keys",
    )
    p.add_argument("--restart", action="store_true", help="start a station that dies again")
    p.add_argument(
        "--console",
        default="0",
        metavar="PORT|none",
        help="the pilot's console, a web page on 127.0.0.1:PORT (default: any free port; docs/console.md)",
    )
    p.add_argument(
        "--ros2",
        choices=ROS2_STATIONS,
        metavar="STATION",
        help="a ROS 2 node takes this station's place: a gateway speaks rmw_zenoh to it "
        f"(choices: {', '.join(ROS2_STATIONS)}; docs/ros2.md)",
    )
    p.add_argument("--ros-domain", type=int, metavar="N", help="with --ros2: ROS_DOMAIN_ID (default 0)")
    p.add_argument(
        "--ros-namespace", metavar="NS", help="with --ros2: the topics' namespace (default /abyss)"
    )
    p.set_defaults(func=cmd_up)


def _add_station(sub: Any) -> None:
    p = sub.add_parser("station", help="run one station, e.g. on its own host")
    p.add_argument("name", choices=keys.STATIONS)
    config_args(p, speed=False)  # --speed scales a replay here; simulated time's: --set time.speed=X
    p.add_argument("--listen", action="append", default=[], metavar="ENDPOINT")
    p.add_argument("--connect", action="append", default=[], metavar="ENDPOINT")
    p.add_argument("--status-file", type=Path, help="write counters here on exit")
    p.add_argument(
        "--console",
        default="none",
        metavar="PORT|none",
        help="onshore only: serve the pilot's console on 127.0.0.1:PORT (0: any free port; docs/console.md)",
    )
    p.add_argument(
        "--link",
        choices=LINK_MODES,
        default="emulated",
        help="emulated (default): in-process, at the station's egress; tun: the in-process links "
        "pass through and a TUN forwarder applies each hop's profile to this host's packets "
        "towards the neighbour, kernel TCP included (needs CAP_NET_ADMIN and /dev/net/tun); "
        "netem: tc/netem on the interface towards the neighbour (needs CAP_NET_ADMIN and "
        "sch_netem); auto: netem, else tun, else emulated, and the log says which",
    )
    p.add_argument(
        "--zenoh-mode",
        choices=("router", "peer"),
        default="router",
        help="router (default): stations on separate hosts route for each other and for tools; "
        "peer: under a router such as `abyss up`'s",
    )
    p.add_argument(
        "--tls",
        type=Path,
        default=os.environ.get(TLS_DIR_ENV) or None,
        metavar="DIR",
        help=f"certificates from `abyss certs make DIR`: TLS on every endpoint (tls/HOST:PORT) "
        f"and access control (default ${TLS_DIR_ENV})",
    )
    p.add_argument(
        "--peer",
        action="append",
        default=[],
        metavar="HOP=HOST",
        help="with --link tun|netem|auto: the neighbour across HOP, whose route is shaped "
        "(default: the neighbour's station name)",
    )
    p.add_argument(
        "--replay",
        type=Path,
        metavar="RUN_DIR",
        help="play this station's messages of a recorded run back instead of running it",
    )
    p.add_argument("--speed", type=float, default=1.0, metavar="X", help="with --replay: time scale")
    p.add_argument("-v", "--verbose", action="store_true")
    p.set_defaults(func=cmd_station)


def _add_health(sub: Any) -> None:
    p = sub.add_parser(
        "health", help="exit 0 when a station's liveliness token is seen (a container's health check)"
    )
    p.add_argument("station", choices=keys.STATIONS)
    connect_args(p)
    p.add_argument("--timeout", type=float, default=3.0, metavar="S")
    p.set_defaults(func=cmd_health)


def _add_certs(sub: Any) -> None:
    certs = sub.add_parser("certs", help="certificates for authenticated links").add_subparsers(
        dest="certs", required=True
    )
    p = certs.add_parser("make", help="a CA and one certificate per station and for the operator's tools")
    p.add_argument("directory", type=Path, metavar="DIR")
    p.add_argument(
        "--host",
        action="append",
        default=[],
        metavar="HOLDER=NAME",
        help="an extra name or address in a holder's certificate (repeatable)",
    )
    p.set_defaults(func=cmd_certs_make)
