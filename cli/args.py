"""What several commands share: configuration options, KEY=VALUE pairs, a tool's session."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

import zenoh

from abyss.bus.session import client_config, open_session
from abyss.common.errors import AbyssError, BusError, ConfigError
from abyss.config import Config, load
from abyss.config.linkprofile import FIELDS
from abyss.config.system import TIME_MODES
from abyss.interface import keys

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"


def config_args(p: argparse.ArgumentParser, speed: bool = True) -> None:
    """The configuration's options; `speed`: with --speed for simulated time (a command whose
    --speed scales a replay has none)."""
    p.add_argument("--config", type=Path, help="TOML configuration file")
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="SECTION.FIELD=VALUE",
        help="override one configuration field",
    )
    p.add_argument("--system", help="system id: keys are abyss/<system>/...")
    p.add_argument(
        "--profile",
        action="append",
        default=[],
        metavar="HOP=NAME",
        help=f"link profile of a hop ({', '.join(keys.HOPS)})",
    )
    p.add_argument("--seed", type=int)
    package_args(p)
    p.add_argument(
        "--hybrid",
        metavar="TOPICS",
        help="a hybrid run: a real vehicle provides these outputs of the simulation (e.g. "
        "nav,joints or nav,joints,sonar: hybrid.vehicle), and the simulation runs as its twin, "
        "rendering the rest at its pose (docs/hybrid.md)",
    )
    p.add_argument(
        "--site-pose",
        metavar="X,Y,Z,HEADING_DEG",
        help="with --hybrid: where the site's origin lies in the real vehicle's navigation frame "
        "[m] and its x axis's heading there [deg] (hybrid.site_origin_m_nav, site_heading_rad)",
    )
    p.add_argument(
        "--time",
        choices=TIME_MODES,
        help="the system's time source: real (the wall clock, the default) or sim (the "
        "simulation's clock drives every station and emulated link)",
    )
    if speed:
        p.add_argument(
            "--speed",
            dest="time_speed",
            metavar="X|max",
            help="with --time sim: simulated seconds per wall second (default 1), or max: as "
            "fast as the slowest station allows",
        )


def cpu_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--cpu",
        action="append",
        default=[],
        metavar="STATION=CORES",
        help="cap a station's CPU, e.g. onboard=0.5 (a cgroup quota: needs root or a delegated "
        "cgroup; the station sheds its oldest frames and the summary says how many)",
    )


def pairs(option: str, items: list[str]) -> list[tuple[str, str]]:
    """KEY=VALUE items of a repeated option."""
    pairs = []
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key or not value:
            raise ConfigError(option, f"{item!r} is not KEY=VALUE")
        pairs.append((key, value))
    return pairs


def load_config(
    args: argparse.Namespace, default: Path | None = None, base: dict[str, Any] | None = None
) -> Config:
    """--config (else `default`, else the table `base`, else the defaults), then --set, --system,
    --seed, --robot, --site, --time, --speed, --profile and --cpu on top."""
    overrides = list(args.set)
    options: dict[str, str] = {}  # a field -> the option that set it, for its error

    def option(name: str, field: str, value: object) -> None:
        overrides.append(f"{field}={value}")
        options[field] = name

    if args.system:
        option("--system", "system", args.system)
    if args.seed is not None:
        option("--seed", "seed", args.seed)
    for name, field in (("robot", "simulation.robot"), ("site", "simulation.site")):
        if getattr(args, name, ""):
            option(f"--{name}", field, getattr(args, name))
    hybrid = getattr(args, "hybrid", None)
    if hybrid is not None and not hybrid.strip(","):
        raise ConfigError(
            "--hybrid", "names what the real vehicle provides, e.g. nav,joints (`abyss keys --hybrid`)"
        )
    if hybrid:
        option("--hybrid", "hybrid.vehicle", json.dumps(args.hybrid.split(",")))
    if getattr(args, "site_pose", None):
        x, y, z, heading_rad = site_pose(args.site_pose)
        option("--site-pose", "hybrid.site_origin_m_nav", json.dumps([x, y, z]))
        option("--site-pose", "hybrid.site_heading_rad", heading_rad)
    if args.time is not None:
        option("--time", "time.mode", args.time)
    if getattr(args, "time_speed", None) is not None:
        option("--speed", "time.speed", args.time_speed)
    for hop, name in pairs("--profile", args.profile):
        option("--profile", f"links.{keys.check_hop(hop)}", name)
    for station, cores in pairs("--cpu", getattr(args, "cpu", [])):
        option("--cpu", f"cpu.{keys.check_station(station)}", cores)
    config = load(args.config or default, overrides, base=base, options=options)
    if getattr(args, "site_pose", None) and not config.hybrid.on:
        raise ConfigError("--site-pose", "places the site for a real vehicle: it goes with --hybrid")
    return config


def site_pose(text: str) -> tuple[float, float, float, float]:
    """--site-pose X,Y,Z,HEADING_DEG: the origin [m] and the heading [rad]."""
    try:
        x, y, z, heading_deg = (float(v) for v in text.split(","))
    except ValueError:
        raise ConfigError("--site-pose", f"{text!r} is not X,Y,Z,HEADING_DEG (four numbers)") from None
    return x, y, z, math.radians(heading_deg)


def profile_args(p: argparse.ArgumentParser) -> None:
    for name in FIELDS:
        p.add_argument(f"--{name.replace('_', '-')}", dest=f"field_{name}", metavar="VALUE")


def profile_fields(args: argparse.Namespace) -> dict[str, str]:
    return {n: getattr(args, f"field_{n}") for n in FIELDS if getattr(args, f"field_{n}") is not None}


class NoSystem(AbyssError):
    """A tool's session found nothing at its endpoint: no system runs there."""

    def __init__(self, endpoint: str, system: str) -> None:
        super().__init__(
            f"no system is running at {endpoint} (system {system}): start one with `abyss up`, or give "
            "--connect the endpoint a running one printed (its run directory's state.json says it)"
        )
        self.endpoint = endpoint
        self.system = system


def client(args: argparse.Namespace) -> zenoh.Session:
    """A tool's session with the running system at --connect; NoSystem where none answers."""
    try:
        return open_session(client_config(args.connect), "abyss")
    except BusError:
        raise NoSystem(args.connect, args.system) from None


def connect_args(p: argparse.ArgumentParser) -> None:
    """--connect and --system of a tool that talks to a running system (`talks_to_system`: a
    session it cannot open means that no system runs there, cli.main says so)."""
    p.add_argument("--connect", default=DEFAULT_ENDPOINT, metavar="ENDPOINT")
    p.add_argument("--system", default="default")
    p.set_defaults(talks_to_system=True)


def package_args(p: argparse.ArgumentParser, robot: bool = True, site: bool = True) -> None:
    """--robot DIR and --site DIR: the robot and site packages (simulation.robot, simulation.site;
    description.robot, description.site) a command runs, or, for a tool that talks to a running system, that
    system runs; the shipped ones by default."""
    if robot:
        p.add_argument(
            "--robot",
            default="",
            metavar="DIR",
            help="the robot package (simulation.robot); default: the shipped ROV",
        )
    if site:
        p.add_argument(
            "--site",
            default="",
            metavar="DIR",
            help="the site package (simulation.site); default: the shipped panel",
        )
